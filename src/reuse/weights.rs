//! The weights of frame reuse, each equation of the paper in one place (derived in
//! `docs/estimators.md`, whose section names the comments cite).
//!
//! A native sample `s = (x, w)` of eye `m` lands in pixel `i` of frame `j`; what it adds there is
//! decided by the method's `Weights`:
//! - `OwnEye` (Havran et al.): the native eye's estimate (7), `FirstHit::radiance`, re-evaluated
//!   for eye `j`; pixels average by count. On diffuse surfaces eq. 14 shows this is what eq. 15
//!   gives too, which is why the unweighted average works there and nowhere else.
//! - `Paper`: eq. 15, `f_j cos L / sum_{visible m'} p(w | x, x->o_m')`: the balance heuristic of
//!   eq. 13 once approximation (10) has made every visible eye's area density `n_r`. With `n_v`
//!   eyes seeing `x`, `n_r n_v` samples are expected per pixel, so the value splatted is `n_r n_v`
//!   times eq. 15, and the pixel divides by the count that landed.
//! - `Exact`: eq. 13 with the exact densities `D_k = n_k(pi_k(x)) J_k(x) vis inside / A_pix,k`:
//!   `(J_j / A_pix,j) f_j cos L / sum_k D_k p(w | x, x->o_k)`, unbiased.
//!
//! The light sample and the emitter reached along `w` use `p + p_l` in the denominators and the
//! self-emission of `x` divides by `sum_k D_k` (docs/estimators.md, "direct light").
use super::Weights;
use crate::bsdf::Material;
use crate::integrator::{facing, FirstHit};
use glam::Vec3;
use std::f32::consts::FRAC_1_PI;

/// The per-eye quantities of one native hit that every method's weights are built from.
#[derive(Clone, Copy, Debug)]
pub struct EyeTerms {
    /// Unit direction from x to the eye.
    pub wo: Vec3,
    /// `J_k / A_pix,k` (film density in pixels per unit area at x), or 0 where eye k cannot see x.
    pub j_over_a: f32,
    /// `n_k(pi_k(x))`: native samples eye k shot in the pixel x projects to (`--spp`, or the
    /// adaptive count of that pixel; docs/estimators.md, "adaptive counts").
    pub n: f32,
    /// The BSDF towards this eye for `w` and for the light sample's direction (zero below the
    /// surface), evaluated once per hit by `denominators` beside the pdfs, for the eyes that
    /// see x; `None` until then.
    pub f: Option<(Vec3, Vec3)>,
}

/// The side of a Lambertian hit's surface an eye sees, where it is not known (the eye cannot
/// see x): `LambertWeighing`'s sides are `Lambert::side_code`'s 0, 1 or 2 otherwise.
pub const SIDE_UNKNOWN: u8 = u8::MAX;

impl EyeTerms {
    pub fn new(wo: Vec3, j_over_a: f32, n: f32) -> EyeTerms {
        EyeTerms {
            wo,
            j_over_a,
            n,
            f: None,
        }
    }
}

/// MIS denominators of one native sample over the eyes of its group (eq. 13's denominator).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Denominators {
    /// `sum_k D_k p_k(w)`: indirect radiance along w.
    pub ind: f32,
    /// `sum_k D_k (p_k(w) + p_l(w))`: the emitter reached along w.
    pub dir_w: f32,
    /// `sum_k D_k (p_k(w_l) + p_l(w_l))`: the light sample.
    pub dir_l: f32,
    /// `sum_k D_k`: self-emission.
    pub emit: f32,
}

/// `D_k(x)` of one eye (0 where it cannot see x): the exact density `n_k J_k / A_pix,k`, or
/// approximation (10), under which every visible eye's density is `n_r`.
pub fn density(weights: Weights, e: &EyeTerms, spp: u32) -> f32 {
    density_of(weights, e.j_over_a, e.n, spp)
}

/// `density` of an eye whose `J_k / A_pix,k` is `j_over_a` and whose count is `n`.
#[inline]
fn density_of(weights: Weights, j_over_a: f32, n: f32, spp: u32) -> f32 {
    if j_over_a <= 0.0 {
        return 0.0;
    }
    match weights {
        Weights::Exact => n * j_over_a,
        Weights::Paper => spp as f32, // approximation (10)
        Weights::None | Weights::OwnEye => 0.0,
    }
}

/// Eq. 13's denominators for `fh` given each eye's terms; fills each seeing eye's BSDF values
/// (`EyeTerms::f`) on the way, from the same evaluations as its pdfs.
pub fn denominators(
    fh: &FirstHit,
    eyes: &mut [EyeTerms],
    spp: u32,
    weights: Weights,
) -> Denominators {
    let m = &fh.m;
    let mut q = Denominators::default();
    for e in eyes.iter_mut() {
        let d = density(weights, e, spp);
        if d == 0.0 {
            continue;
        }
        // The eye's lobe, on its side of the surface.
        let (ng, ns) = facing(&fh.sp, e.wo);
        let eval_pdf = |w: Vec3| {
            if ng.dot(w) > 0.0 {
                m.eval_and_pdf(ns, e.wo, w)
            } else {
                (Vec3::ZERO, 0.0)
            }
        };
        let (mut f_w, mut f_l) = (Vec3::ZERO, Vec3::ZERO);
        q.emit += d;
        if let Some(w) = fh.w {
            let (f, p) = eval_pdf(w);
            f_w = f;
            q.ind += d * p;
            q.dir_w += d * (p + fh.pdf_light_w);
        }
        if let Some(l) = &fh.light {
            let (f, p) = eval_pdf(l.wi);
            f_l = f;
            q.dir_l += d * (p + l.pdf);
        }
        e.f = Some((f_w, f_l));
    }
    q
}

/// A first hit on a Lambertian surface that does not emit: its BSDF `Kd / pi` and its pdf
/// `cos / pi` are the same for every eye on one side of the surface whose shading normal faces
/// it, so the pdfs of `w` and of the light sample's direction, and the balance-heuristic sum
/// before its scale, are computed once per side and hit instead of once per eye (the same
/// operations in the same order as the general path, so the same bits).
#[derive(Clone, Copy)]
struct Lambert {
    ng: Vec3,
    ns: Vec3,
    kd_pi: Vec3,
    /// Per side (0: the side `ng` points to, 1: the other): `p(w)` and `p(w_l)`, each zero where
    /// the direction is below the surface or the shading normal.
    pdf_w: [f32; 2],
    pdf_l: [f32; 2],
}

impl Lambert {
    // Inlined: returned through memory, the record's wide loads of what narrow stores had
    // just written stalled (6% of the reuse kernel's samples in `perf`).
    #[inline(always)]
    fn of(m: &Material, fh: &FirstHit) -> Option<Lambert> {
        if m.ks.max_element() > 0.0 || m.is_emissive() {
            return None;
        }
        let (ng, ns) = (fh.sp.ng, fh.sp.ns);
        // As `facing` and `Material::pdf` for an eye on side `s` (with the diffuse weight 1).
        let pdf = |s: usize, w: Option<Vec3>| {
            let (ng, ns) = if s == 0 { (ng, ns) } else { (-ng, -ns) };
            match w {
                Some(w) if ng.dot(w) > 0.0 && ns.dot(w) > 0.0 => 1.0 * ns.dot(w) * FRAC_1_PI,
                _ => 0.0,
            }
        };
        let wl = fh.light.map(|l| l.wi);
        Some(Lambert {
            ng,
            ns,
            kd_pi: m.kd * FRAC_1_PI,
            pdf_w: [pdf(0, fh.w), pdf(1, fh.w)],
            pdf_l: [pdf(0, wl), pdf(1, wl)],
        })
    }

    /// The side of the eye in direction `wo`, and whether the shading normal on that side
    /// faces it (else the BSDF and its pdfs are zero for that eye).
    #[inline]
    fn side(&self, wo: Vec3) -> (usize, bool) {
        if self.ng.dot(wo) >= 0.0 {
            (0, self.ns.dot(wo) > 0.0)
        } else {
            (1, (-self.ns).dot(wo) > 0.0)
        }
    }

    /// `side` as one number: the side where its shading normal faces the eye, else 2.
    #[inline]
    fn side_code(&self, wo: Vec3) -> u8 {
        match self.side(wo) {
            (s, true) => s as u8,
            (_, false) => 2,
        }
    }

    /// `(p(w), p(w_l))` for the eye whose `side_code` is `side`.
    #[inline]
    fn pdfs_of(&self, side: u8) -> (f32, f32) {
        match side {
            0 | 1 => (self.pdf_w[side as usize], self.pdf_l[side as usize]),
            _ => (0.0, 0.0),
        }
    }

    /// The balance-heuristic sum of `balance` before its scale, for an eye on side `s` whose
    /// shading normal faces it.
    fn sum(&self, fh: &FirstHit, q: &Denominators, s: usize) -> Vec3 {
        let (ng, ns) = if s == 0 {
            (self.ng, self.ns)
        } else {
            (-self.ng, -self.ns)
        };
        let mut l = Vec3::ZERO;
        if let Some(ls) = &fh.light {
            if ls.le != Vec3::ZERO && ng.dot(ls.wi) > 0.0 && q.dir_l > 0.0 {
                let f = if ns.dot(ls.wi) > 0.0 {
                    self.kd_pi
                } else {
                    Vec3::ZERO
                };
                l += f * ns.dot(ls.wi) * ls.le / q.dir_l;
            }
        }
        if let Some(w) = fh.w {
            if ng.dot(w) > 0.0 {
                let f = if ns.dot(w) > 0.0 {
                    self.kd_pi
                } else {
                    Vec3::ZERO
                };
                let fc = f * ns.dot(w);
                if q.dir_w > 0.0 {
                    l += fc * fh.le_w / q.dir_w;
                }
                if q.ind > 0.0 {
                    l += fc * fh.li_w / q.ind;
                }
            }
        }
        l
    }
}

/// The weights of one native hit over the eyes of its group, ready to give its value in any
/// of them.
pub struct Weighing<'a> {
    weights: Weights,
    fh: &'a FirstHit,
    q: Denominators,
    /// `n_r n_v`: the paper's count average (see the module note).
    paper_scale: f32,
}

impl<'a> Weighing<'a> {
    pub fn new(
        weights: Weights,
        fh: &'a FirstHit,
        eyes: &mut [EyeTerms],
        spp: u32,
    ) -> Weighing<'a> {
        let q = match weights {
            Weights::Paper | Weights::Exact => denominators(fh, eyes, spp, weights),
            Weights::None | Weights::OwnEye => Denominators::default(),
        };
        let visible = eyes.iter().filter(|e| e.j_over_a > 0.0).count();
        Weighing {
            weights,
            fh,
            q,
            paper_scale: (spp as usize * visible) as f32,
        }
    }

    pub fn denominators(&self) -> &Denominators {
        &self.q
    }

    /// What the sample splats into the pixel it lands in of the eye at `eye`, with terms `e`.
    pub fn value(&self, eye: Vec3, e: &EyeTerms) -> Vec3 {
        match self.weights {
            // Estimator (7) with the native eye's densities.
            Weights::None | Weights::OwnEye => self.fh.radiance(eye),
            // `n_r n_v` times eq. 15.
            Weights::Paper => self.balance(eye, e, self.paper_scale),
            // Eq. 13 with exact densities: `J_j / A_pix,j` times the balance-heuristic sum.
            Weights::Exact => self.balance(eye, e, e.j_over_a),
        }
    }

    /// `scale` times the balance-heuristic contribution of the sample to the eye at `eye`
    /// (terms `e`): self-emission, the light sample, the emitter reached along `w` and the rest
    /// of the walk, each over its denominator.
    fn balance(&self, eye: Vec3, e: &EyeTerms, scale: f32) -> Vec3 {
        let (fh, q) = (self.fh, &self.q);
        let wo = e.wo;
        let sp = &fh.sp;
        let m = &fh.m;
        let (ng, ns) = facing(sp, wo);
        let mut l = Vec3::ZERO;
        if q.emit > 0.0 {
            l += crate::scene::Scene::emitted_by(m, sp, eye) / q.emit;
        }
        if let Some(ls) = &fh.light {
            if ls.le != Vec3::ZERO && ng.dot(ls.wi) > 0.0 && q.dir_l > 0.0 {
                let f = e.f.map_or_else(|| m.eval(ns, wo, ls.wi), |(_, f_l)| f_l);
                l += f * ns.dot(ls.wi) * ls.le / q.dir_l;
            }
        }
        if let Some(w) = fh.w {
            if ng.dot(w) > 0.0 {
                let f = e.f.map_or_else(|| m.eval(ns, wo, w), |(f_w, _)| f_w);
                let fc = f * ns.dot(w);
                if q.dir_w > 0.0 {
                    l += fc * fh.le_w / q.dir_w;
                }
                if q.ind > 0.0 {
                    l += fc * fh.li_w / q.ind;
                }
            }
        }
        l * scale
    }
}

/// The weights of a native hit on a Lambertian surface that does not emit (most hits of most
/// scenes), for `Paper` and `Exact`, built straight from how each eye of the group sees it,
/// without `EyeTerms`: what `Weighing`'s general path (each eye's BSDF and pdfs) gives, to the
/// bit (the unit test compares them), for the cost of the per-eye facts alone (the side of the surface each eye sees, and
/// its density). What the kernel splats per eye is then one product, `value`.
pub struct LambertWeighing {
    q: Denominators,
    /// The balance-heuristic sum per side (`Lambert::sum`).
    sums: [Vec3; 2],
    exact: bool,
    /// `n_r n_v` (`Weighing::paper_scale`).
    paper_scale: f32,
}

impl LambertWeighing {
    /// `None` unless `weights` is `Paper` or `Exact` and `fh` is on a Lambertian surface that
    /// does not emit. `eye(k)`: how eye `k` of the `n_f` sees x, `(wo, J_k / A_pix,k, n_k)`, or
    /// `None` where it cannot (occluded or off its film). Writes the side of the surface each eye
    /// that sees x is on (`Lambert::side_code`) into `sides[k]`, `SIDE_UNKNOWN` for the others;
    /// `value` takes it.
    #[inline]
    pub fn new(
        weights: Weights,
        fh: &FirstHit,
        spp: u32,
        n_f: usize,
        eye: impl Fn(usize) -> Option<(Vec3, f32, f32)>,
        sides: &mut [u8],
    ) -> Option<LambertWeighing> {
        let exact = match weights {
            Weights::Exact => true,
            Weights::Paper => false,
            Weights::None | Weights::OwnEye => return None,
        };
        let lambert = Lambert::of(&fh.m, fh)?;
        // `denominators`' Lambertian loop, and `Weighing::new`'s count of the eyes that see x.
        // Without a branch per eye on `w` and the light sample: a sum that has no term is
        // set to zero after (what it stays at where it is skipped).
        let mut q = Denominators::default();
        let mut visible = 0usize;
        let pdf_light_l = fh.light.map_or(0.0, |l| l.pdf);
        for (k, side) in sides.iter_mut().enumerate().take(n_f) {
            *side = SIDE_UNKNOWN;
            let Some((wo, j_over_a, n)) = eye(k) else {
                continue;
            };
            visible += usize::from(j_over_a > 0.0);
            // (The side of an eye of density zero too: its value is zero times its sum.)
            *side = lambert.side_code(wo);
            let d = density_of(weights, j_over_a, n, spp);
            if d == 0.0 {
                continue;
            }
            let (p_w, p_l) = lambert.pdfs_of(*side);
            q.emit += d;
            q.ind += d * p_w;
            q.dir_w += d * (p_w + fh.pdf_light_w);
            q.dir_l += d * (p_l + pdf_light_l);
        }
        if fh.w.is_none() {
            (q.ind, q.dir_w) = (0.0, 0.0);
        }
        if fh.light.is_none() {
            q.dir_l = 0.0;
        }
        Some(LambertWeighing {
            sums: [lambert.sum(fh, &q, 0), lambert.sum(fh, &q, 1)],
            q,
            exact,
            paper_scale: (spp as usize * visible) as f32,
        })
    }

    pub fn denominators(&self) -> &Denominators {
        &self.q
    }

    /// `Weighing::value` for an eye that sees x, on side `side` (`Lambert::side_code`) with
    /// `J_k / A_pix,k` = `j_over_a`.
    #[inline]
    pub fn value(&self, side: u8, j_over_a: f32) -> Vec3 {
        let scale = if self.exact {
            j_over_a
        } else {
            self.paper_scale
        };
        match side {
            0 | 1 => self.sums[side as usize] * scale,
            _ => Vec3::ZERO * scale,
        }
    }
}

/// Each visible eye's balance weight for the indirect part, `D_k p_k(w) / sum_k' D_k' p_k'(w)`,
/// as the estimator computes it (zero for the eyes that cannot see x). They sum to one wherever
/// some eye can have drawn `w`: what the weights test checks.
pub fn indirect_weights(fh: &FirstHit, eyes: &[EyeTerms], spp: u32, weights: Weights) -> Vec<f32> {
    let q = denominators(fh, &mut eyes.to_vec(), spp, weights);
    let m = &fh.m;
    let Some(w) = fh.w else {
        return vec![0.0; eyes.len()];
    };
    eyes.iter()
        .map(|e| {
            if q.ind > 0.0 {
                density(weights, e, spp) * eye_pdf(m, fh, e, w) / q.ind
            } else {
                0.0
            }
        })
        .collect()
}

/// The density eye `e` samples `w` with at the hit: its lobe, on its side of the surface.
fn eye_pdf(m: &Material, fh: &FirstHit, e: &EyeTerms, w: Vec3) -> f32 {
    let (ng, ns) = facing(&fh.sp, e.wo);
    if ng.dot(w) > 0.0 {
        m.pdf(ns, e.wo, w)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::integrator::FirstLight;
    use crate::sampling::mix64;
    use crate::scene::SurfacePoint;

    fn unit(h: u64) -> f32 {
        (h >> 40) as f32 / (1u64 << 24) as f32
    }

    fn direction(h: u64) -> Vec3 {
        let v = Vec3::new(unit(mix64(h)), unit(mix64(h + 1)), unit(mix64(h + 2)));
        (v - 0.5).normalize()
    }

    #[test]
    fn the_lambertian_weights_are_the_general_ones_to_the_bit() {
        // Lambertian hits with shading normals off the geometric ones, `w` and the light sample
        // on either side or missing, and eyes on both sides, some unseeing, some of zero
        // density (grazing, or no native sample in their pixel): `LambertWeighing` gives
        // `Weighing`'s denominators and values bit for bit (its general path: each eye's BSDF
        // and pdfs from `Material::eval_and_pdf`), with both weights.
        let mut compared = 0;
        for i in 0..3000u64 {
            let h = |j: u64| mix64(i * 64 + j);
            let ng = direction(h(0));
            let ns = (ng + 0.3 * direction(h(1))).normalize();
            let sp = SurfacePoint {
                ng,
                ns,
                ..Default::default()
            };
            let fh = FirstHit {
                sp,
                m: Material {
                    kd: Vec3::new(0.2, 0.5, 0.7) * unit(h(2)),
                    ..Default::default()
                },
                w: (h(3) % 5 != 0).then(|| direction(h(4))),
                le_w: Vec3::splat(unit(h(5)) * 3.0) * (h(6) % 3 == 0) as u8 as f32,
                pdf_light_w: unit(h(7)),
                li_w: Vec3::new(unit(h(8)), 0.4, 0.1),
                light: (h(9) % 4 != 0).then(|| FirstLight {
                    wi: direction(h(10)),
                    le: Vec3::splat(5.0) * (h(11) % 5 != 0) as u8 as f32,
                    pdf: unit(h(12)) * 2.0,
                }),
                ..Default::default()
            };
            let n_f = 1 + (h(13) % 9) as usize;
            let spp = 1 + (h(14) % 3) as u32;
            // Per eye: None (cannot see x) or (wo, J/A, n).
            let seen: Vec<Option<(Vec3, f32, f32)>> = (0..n_f as u64)
                .map(|k| {
                    let g = |j: u64| mix64(h(20 + k) ^ j);
                    (g(0) % 4 != 0).then(|| {
                        let j_over_a = if g(1) % 6 == 0 {
                            0.0
                        } else {
                            unit(g(2)) * 40.0
                        };
                        let n = if g(3) % 7 == 0 {
                            0.0
                        } else {
                            (g(4) % 4) as f32
                        };
                        (direction(g(5)), j_over_a, n)
                    })
                })
                .collect();
            for weights in [Weights::Exact, Weights::Paper] {
                // The terms as the kernel builds them for `Weighing`.
                let mut eyes: Vec<EyeTerms> = seen
                    .iter()
                    .map(|s| match *s {
                        Some((wo, j, n)) => EyeTerms::new(wo, j, n),
                        None => EyeTerms::new(Vec3::ONE.normalize(), 0.0, 0.0),
                    })
                    .collect();
                let general = Weighing::new(weights, &fh, &mut eyes, spp);
                let mut sides = vec![0u8; n_f];
                let lambert = LambertWeighing::new(weights, &fh, spp, n_f, |k| seen[k], &mut sides)
                    .expect("a Lambertian hit");
                let bits = |q: &Denominators| [q.ind, q.dir_w, q.dir_l, q.emit].map(f32::to_bits);
                assert_eq!(bits(general.denominators()), bits(lambert.denominators()));
                for (k, s) in seen.iter().enumerate() {
                    if let Some((_, j, _)) = s {
                        let a = general.value(Vec3::ZERO, &eyes[k]).to_array();
                        let b = lambert.value(sides[k], *j).to_array();
                        assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits), "hit {i} eye {k}");
                        compared += 1;
                    }
                }
            }
        }
        assert!(compared > 10_000, "{compared} values compared");
        // Hits the general weights must take: glossy, emitting, and the count-averaged methods.
        let glossy = FirstHit {
            m: Material {
                ks: Vec3::splat(0.1),
                ..Default::default()
            },
            ..Default::default()
        };
        let emitting = FirstHit {
            m: Material {
                ke: Vec3::ONE,
                ..Default::default()
            },
            ..Default::default()
        };
        let mut sides = [0u8; 1];
        let none = |_| Some((Vec3::Z, 1.0, 1.0));
        for (fh, weights) in [
            (&glossy, Weights::Exact),
            (&emitting, Weights::Paper),
            (&FirstHit::default(), Weights::OwnEye),
            (&FirstHit::default(), Weights::None),
        ] {
            assert!(LambertWeighing::new(weights, fh, 1, 1, none, &mut sides).is_none());
        }
    }
}
