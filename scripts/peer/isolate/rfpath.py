"""A Python port of Mitsuba 3.9.1's `path` integrator (src/integrators/path.cpp), primal only,
with two switches so that Mitsuba's samplers can drive reframe's exact estimator:

  rr_mode  'mitsuba': path.cpp's roulette: after vertex d's light sample and BSDF sample, before
                      the BSDF ray's emitter hit is counted, when d >= rr_depth (d = 1 for the
                      first hit); q = min(max(throughput incl. vertex 1), .95).
           'reframe': src/integrator/mod.rs `walk_continue`: after the BSDF ray from vertex d found its
                      next vertex and that vertex's emission (MIS-weighted) was added, when
                      d >= rr_depth; q = min(max(beta), .95) where beta omits the first vertex's
                      f cos / p (the walk's beta starts at 1 at vertex 2).
  mis      'power' (Mitsuba) or 'balance' (reframe).

The sampler dimensions are drawn in path.cpp's order in both modes (light 2D, lobe 1D, BSDF 2D,
roulette 1D per vertex); in 'reframe' mode the roulette number drawn at the end of vertex d is
used at the top of the next iteration, after the emission the BSDF ray found.
"""
import drjit as dr
import mitsuba as mi
from mitsuba.ad.integrators.common import RBIntegrator


class RfPath(RBIntegrator):
    def __init__(self, props):
        super().__init__(props)
        self.rr_mode = props.get("rr_mode", "mitsuba")
        self.mis = props.get("mis", "power")
        assert self.rr_mode in ("mitsuba", "reframe") and self.mis in ("power", "balance")

    def mis_weight(self, a, b):
        if self.mis == "power":
            a, b = a * a, b * b
        w = a / (a + b)
        return dr.select(dr.isfinite(w), w, 0.0)

    @dr.syntax
    def sample(self, mode, scene, sampler, ray, δL, state_in, active, **kwargs):
        assert mode == dr.ADMode.Primal
        rf = self.rr_mode == "reframe"
        bsdf_ctx = mi.BSDFContext()
        ray = mi.Ray3f(dr.detach(ray))
        depth = mi.UInt32(0)
        L = mi.Spectrum(0)
        β = mi.Spectrum(1)
        β_rf = mi.Spectrum(1)     # reframe's beta: without the first vertex's weight
        active = mi.Bool(active)
        pi = scene.ray_intersect_preliminary(ray, coherent=True, reorder=False, active=active)
        si_prev = dr.zeros(mi.SurfaceInteraction3f)
        bsdf_pdf_prev = mi.Float(1.0)
        bsdf_delta_prev = mi.Bool(True)
        rr_pending = mi.Bool(False)
        rr_q = mi.Float(1.0)
        rr_u = mi.Float(0.0)

        while dr.hint(active, max_iterations=self.max_depth, label="RfPath"):
            si = pi.compute_surface_interaction(ray, ray_flags=mi.RayFlags.All)
            bsdf = si.bsdf(ray)
            # Emission found by the previous vertex's BSDF ray (or seen directly).
            ds = mi.DirectionSample3f(scene, si=si, ref=si_prev)
            em_pdf = scene.pdf_emitter_direction(si_prev, ds, ~bsdf_delta_prev)
            mis = self.mis_weight(bsdf_pdf_prev, em_pdf)
            L += β * mis * ds.emitter.eval(si, bsdf_pdf_prev > 0)

            active_next = (depth + 1 < self.max_depth) & si.is_valid()
            if dr.hint(rf, mode="scalar"):
                # reframe: roulette after that emission was counted.
                killed = rr_pending & (rr_u >= rr_q)
                active_next &= ~killed
                β[rr_pending] = β / rr_q
                β_rf[rr_pending] = β_rf / rr_q

            active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            ds, em_weight = scene.sample_emitter_direction(si, sampler.next_2d(), True, active_em)
            active_em &= ds.pdf != 0.0
            wo = si.to_local(ds.d)

            s1 = sampler.next_1d()
            s2 = sampler.next_2d()
            bsdf_val, bsdf_pdf, bsdf_sample, bsdf_weight = bsdf.eval_pdf_sample(
                bsdf_ctx, si, wo, s1, s2, active_next)
            mis_em = dr.select(ds.delta, 1.0, self.mis_weight(ds.pdf, bsdf_pdf))
            L[active_em] = L + β * bsdf_val * em_weight * mis_em

            ray = si.spawn_ray(si.to_world(bsdf_sample.wo))
            β *= bsdf_weight
            β_rf[depth > 0] = β_rf * bsdf_weight
            si_prev = dr.detach(si, True)
            bsdf_pdf_prev = bsdf_sample.pdf
            bsdf_delta_prev = mi.has_flag(bsdf_sample.sampled_type, mi.BSDFFlags.Delta)

            depth[si.is_valid()] += 1
            β_max = dr.max(mi.unpolarized_spectrum(β))
            u = sampler.next_1d()
            if dr.hint(rf, mode="scalar"):
                rr_pending = depth >= self.rr_depth
                rr_q = dr.minimum(dr.max(mi.unpolarized_spectrum(β_rf)), 0.95)
                rr_u = u
            else:
                rr_prob = dr.minimum(β_max, 0.95)
                rr_active = depth >= self.rr_depth
                β[rr_active] = β / rr_prob
                active_next &= ~rr_active | (u < rr_prob)

            active = active_next & (β_max != 0)
            pi = scene.ray_intersect_preliminary(ray, coherent=False, reorder=False,
                                                 active=active)

        return (L, mi.Bool(True), [], L)


mi.register_integrator("rfpath", lambda props: RfPath(props))
