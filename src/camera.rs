//! Pinhole cameras and the camera path of an animation.
//!
//! A frame's camera comes from a `Pose` (eye, viewing direction, up hint, vertical fov): from
//! `[[keyframe]]` tables interpolated linearly or by a Catmull-Rom spline over their frame
//! numbers (`CameraPath`; the spline is derived in docs/camera.md), or from a camera file that
//! gives every frame (`Cameras::PerFrame`, a pose per frame, e.g. from a camera-to-world matrix:
//! `Pose::from_camera_to_world`).
//!
//! A `Camera` generates primary rays and, for frame reuse, does the reverse: projects a surface
//! point into its film (`project`) and gives the film-to-surface Jacobian `J(x)` that turns a
//! uniform density on the film into an area density on the surface (docs/estimators.md, "The camera's area density").
//! The film sits at focal distance `f = 1` in front of the eye; raster coordinates run from
//! (0, 0) at the top-left corner to (width, height).
//!
//! ```
//! use reframe::camera::{Camera, Keyframe};
//! use glam::Vec3;
//! let k = Keyframe { frame: 0, position: Vec3::new(0.0, 0.0, 5.0), look_at: Vec3::ZERO, up: Vec3::Y, fov: 40.0 };
//! let cam = Camera::new(&k, 64, 48);
//! let centre = cam.project(Vec3::ZERO).unwrap();
//! assert!((centre.x - 32.0).abs() < 1e-3 && (centre.y - 24.0).abs() < 1e-3);
//! ```
use glam::{DVec3, Mat4, Vec2, Vec3, Vec4};
use serde::Deserialize;

/// One camera keyframe of a scene file (fov: vertical, in degrees).
#[derive(Clone, Debug, PartialEq)]
pub struct Keyframe {
    pub frame: u32,
    pub position: Vec3,
    pub look_at: Vec3,
    pub up: Vec3,
    pub fov: f32,
}

impl Keyframe {
    /// The pose of this keyframe: viewing direction `look_at - position`.
    pub fn pose(&self) -> Pose {
        Pose {
            eye: self.position,
            view: self.look_at - self.position,
            up: self.up,
            fov: self.fov,
        }
    }
}

/// Where a camera is and where it looks, what `Camera::new` builds a camera from (fov: vertical,
/// in degrees).
#[derive(Clone, Debug, PartialEq)]
pub struct Pose {
    pub eye: Vec3,
    /// The viewing direction, of any positive length.
    pub view: Vec3,
    /// Up hint: the camera's up is its part perpendicular to `view`.
    pub up: Vec3,
    pub fov: f32,
}

impl Pose {
    /// The pose of a camera-to-world matrix `m` (row-major, translation in the last column, the
    /// camera looking down its -Z with +Y up, as Blender's `matrix_world` of a camera): eye the
    /// translation, view -Z, up hint +Y. Only rotation and translation are used: a scale of the
    /// axes drops out, and a shear is removed the way `Camera::new` orthonormalises (the view
    /// direction kept, up made perpendicular to it). The caller checks that the 3x3 part is
    /// invertible and not mirrored.
    pub fn from_camera_to_world(m: &[f64; 16], fov: f32) -> Pose {
        let col = |c: usize| DVec3::new(m[c], m[4 + c], m[8 + c]);
        let dir = |c: usize| direction(col(c)).unwrap_or(DVec3::ZERO);
        Pose {
            eye: col(3).as_vec3(),
            view: (-dir(2)).as_vec3(),
            up: dir(1).as_vec3(),
            fov,
        }
    }

    /// Why this pose makes no camera (view or up degenerate), if it does not.
    ///
    /// Directions are found as `Camera::from_pose` finds them (`unit`), so only a view or up of
    /// length zero is refused: a scene modelled in tiny units renders as it does at any scale
    /// (a view of 3e-7 units was refused under a fixed 1e-6, and an up of 1e-19 passed here
    /// but made the camera's axes NaN).
    pub fn fault(&self) -> Option<String> {
        // A vector whose every component is below the smallest normal float: the render's
        // threads flush such numbers to zero (as Embree asks), so its axes came out NaN and
        // every frame black, though it has a direction here.
        let subnormal = |v: Vec3| v != Vec3::ZERO && v.abs().max_element() < f32::MIN_POSITIVE;
        if subnormal(self.view) {
            return Some(format!(
                "look_at is {:e} from position, closer than the render's arithmetic resolves \
                 (below {:e})",
                self.view.abs().max_element(),
                f32::MIN_POSITIVE
            ));
        }
        if subnormal(self.up) {
            return Some(format!(
                "up [{:e}, {:e}, {:e}] is shorter than the render's arithmetic resolves (every \
                 component below {:e}): give it at a usual size, e.g. [0, 1, 0]",
                self.up.x,
                self.up.y,
                self.up.z,
                f32::MIN_POSITIVE
            ));
        }
        match (unit(self.view), unit(self.up)) {
            (None, _) => Some("look_at coincides with position".to_string()),
            (_, None) => Some("up has zero length".to_string()),
            (Some(v), Some(u)) if v.cross(u).length() <= 1e-4 => {
                Some(format!("up {} is parallel to the view direction", self.up))
            }
            _ => None,
        }
    }
}

/// `v` made unit length, `None` for a zero vector (or one not finite): divided by its largest
/// element first where its squared length is not a normal float, so that a tiny vector keeps
/// its direction (`up = [0, 1e-19, 0]` made the camera's axes NaN and every frame black);
/// elsewhere `normalize`, to the bit.
pub fn unit(v: Vec3) -> Option<Vec3> {
    let l2 = v.length_squared();
    if l2.is_finite() && l2 >= f32::MIN_POSITIVE {
        return Some(v.normalize());
    }
    let big = v.abs().max_element();
    (big > 0.0 && big.is_finite()).then(|| (v / big).normalize())
}

/// `v` made unit length, `None` for a zero vector: divided by its largest element first, so
/// that a column of a matrix scaled by 1e-200 (whose squared length underflows to 0) keeps its
/// direction.
pub fn direction(v: DVec3) -> Option<DVec3> {
    let l2 = v.length_squared();
    if l2.is_finite() && l2 >= f64::MIN_POSITIVE {
        // As `normalize` has always made it (the same bits).
        return Some(v.normalize());
    }
    let big = v.abs().max_element();
    (big > 0.0 && big.is_finite()).then(|| (v / big).normalize())
}

#[derive(Clone, Debug)]
pub struct Camera {
    /// The eye, where the render has it: `world_eye`, less the scene's `origin`
    /// (`Scene::camera`).
    pub eye: Vec3,
    /// The eye in the scene file's coordinates, where the frames' camera matrices put it.
    pub world_eye: Vec3,
    /// Unit forward (z_m), right and up axes.
    pub forward: Vec3,
    pub right: Vec3,
    pub up: Vec3,
    pub tan_half_fov: f32,
    pub aspect: f32,
    pub width: u32,
    pub height: u32,
}

impl Camera {
    pub fn new(k: &Keyframe, width: u32, height: u32) -> Camera {
        Camera::from_pose(&k.pose(), width, height)
    }

    pub fn from_pose(p: &Pose, width: u32, height: u32) -> Camera {
        // `fault` has made sure both are some direction; `unit` is `normalize` but for tiny
        // vectors (an up of 1e-19, or a cross product of that size).
        let forward = unit(p.view).unwrap_or(Vec3::NAN);
        let right = unit(forward.cross(p.up)).unwrap_or(Vec3::NAN);
        let up = right.cross(forward);
        Camera {
            eye: p.eye,
            world_eye: p.eye,
            forward,
            right,
            up,
            tan_half_fov: (p.fov.to_radians() * 0.5).tan(),
            aspect: width as f32 / height as f32,
            width,
            height,
        }
    }

    /// Unit direction through raster position `r`.
    #[inline]
    pub fn direction(&self, r: Vec2) -> Vec3 {
        let sx = (2.0 * r.x / self.width as f32 - 1.0) * self.tan_half_fov * self.aspect;
        let sy = (1.0 - 2.0 * r.y / self.height as f32) * self.tan_half_fov;
        (self.forward + self.right * sx + self.up * sy).normalize()
    }

    /// Raster position of `x`, if it is in front of the eye and inside the film.
    #[inline]
    pub fn project(&self, x: Vec3) -> Option<Vec2> {
        self.project_offset(x - self.eye)
    }

    /// Raster position of the direction `d` from the eye (a point at infinity), if it is on the
    /// film: projected as a direction, not as the point `eye + d`, which f32 rounds by the
    /// eye's distance from the origin (a scene scaled by 2^16 put the background of the reuse
    /// methods in the wrong pixels, a pattern along the film's border).
    #[inline]
    pub fn project_dir(&self, d: Vec3) -> Option<Vec2> {
        self.project_offset(d)
    }

    /// Index (row-major) of the pixel the direction `d` from the eye lands in (`project_dir`).
    #[inline]
    pub fn pixel_of_dir(&self, d: Vec3) -> Option<u32> {
        self.project_dir(d)
            .map(|r| r.y as u32 * self.width + r.x as u32)
    }

    /// Raster position of the point at offset `c` from the eye, if it is on the film.
    #[inline]
    fn project_offset(&self, c: Vec3) -> Option<Vec2> {
        let z = c.dot(self.forward);
        if z <= 0.0 {
            return None;
        }
        let sx = c.dot(self.right) / (z * self.tan_half_fov * self.aspect);
        let sy = c.dot(self.up) / (z * self.tan_half_fov);
        let r = Vec2::new(
            (sx + 1.0) * 0.5 * self.width as f32,
            (1.0 - sy) * 0.5 * self.height as f32,
        );
        (r.x >= 0.0 && r.y >= 0.0 && r.x < self.width as f32 && r.y < self.height as f32)
            .then_some(r)
    }

    /// Index (row-major) of the pixel `x` projects into, if it is on the film.
    #[inline]
    pub fn pixel_of(&self, x: Vec3) -> Option<u32> {
        self.project(x)
            .map(|r| r.y as u32 * self.width + r.x as u32)
    }

    /// How far the film's corner is from its centre at focal distance 1 (`tan(fov/2)` times the
    /// half-diagonal over the half-height): `1/cos^3` of the widest angle off the axis, which
    /// the film densities (`jacobian`) reach, is about its cube.
    pub fn film_extent(&self) -> f32 {
        self.tan_half_fov * (1.0 + self.aspect * self.aspect).sqrt()
    }

    /// Film area at focal distance 1 (`A_m`).
    pub fn film_area(&self) -> f32 {
        4.0 * self.tan_half_fov * self.tan_half_fov * self.aspect
    }

    /// Film area of one pixel (`A_pix,m = A_m / P`).
    pub fn pixel_area(&self) -> f32 {
        self.film_area() / (self.width as f32 * self.height as f32)
    }

    /// `dA_film / dA_x = f^2 cos_x / (cos_t^3 d^2)` (docs/estimators.md, `J`), without the visibility
    /// and inside-the-film factors, for a point `x` with unit geometric normal `n` that is in
    /// front of the eye.
    #[inline]
    pub fn jacobian(&self, x: Vec3, n: Vec3) -> f32 {
        let c = x - self.eye;
        let d2 = c.length_squared();
        let d = d2.sqrt();
        let cos_t = c.dot(self.forward) / d;
        let cos_x = n.dot(-c).abs() / d;
        cos_x / (cos_t * cos_t * cos_t * d2)
    }

    /// The unit direction from `x` to the eye and `jacobian(x, n)`, sharing their distance (the
    /// same operations as `(eye - x).normalize()` and `jacobian`, so the same bits).
    #[inline]
    pub fn view_terms(&self, x: Vec3, n: Vec3) -> (Vec3, f32) {
        let c = x - self.eye;
        let d2 = c.length_squared();
        let d = d2.sqrt();
        let wo = (self.eye - x) * d.recip();
        let cos_t = c.dot(self.forward) / d;
        let cos_x = n.dot(-c).abs() / d;
        (wo, cos_x / (cos_t * cos_t * cos_t * d2))
    }

    /// `dA_film / dw = f^2 / cos_t^3` for the unit direction `d` from the eye: the film density
    /// of a direction (a point at infinity; docs/estimators.md, "Control variate"), 0 behind the
    /// eye. Without the inside-the-film factor.
    #[inline]
    pub fn jacobian_dir(&self, d: Vec3) -> f32 {
        let cos_t = d.dot(self.forward);
        if cos_t <= 0.0 {
            0.0
        } else {
            1.0 / (cos_t * cos_t * cos_t)
        }
    }

    /// World to camera space, camera space as OpenEXR's standard `worldToCamera` defines it
    /// (x right, y up, z the viewing direction), as a column-vector matrix. World is the scene
    /// file's space (`world_eye`), what the frames' metadata records.
    pub fn world_to_camera(&self) -> Mat4 {
        let e = self.world_eye;
        Mat4::from_cols(
            Vec4::new(self.right.x, self.up.x, self.forward.x, 0.0),
            Vec4::new(self.right.y, self.up.y, self.forward.y, 0.0),
            Vec4::new(self.right.z, self.up.z, self.forward.z, 0.0),
            Vec4::new(
                -self.right.dot(e),
                -self.up.dot(e),
                -self.forward.dot(e),
                1.0,
            ),
        )
    }

    /// World to OpenEXR NDC ((0,0) top-left, (1,1) bottom-right of the image, after the
    /// homogeneous divide), as a column-vector matrix.
    pub fn world_to_ndc(&self) -> Mat4 {
        let (th, a) = (self.tan_half_fov, self.aspect);
        // x_ndc = 0.5 + 0.5 x_c / (z_c th a), y_ndc = 0.5 - 0.5 y_c / (z_c th); w = z_c.
        let proj = Mat4::from_cols(
            Vec4::new(0.5 / (th * a), 0.0, 0.0, 0.0),
            Vec4::new(0.0, -0.5 / th, 0.0, 0.0),
            Vec4::new(0.5, 0.5, 1.0, 1.0),
            Vec4::new(0.0, 0.0, 0.0, 0.0),
        );
        proj * self.world_to_camera()
    }
}

/// How `[[keyframe]]` tables are interpolated between them (the scene TOML's `interpolation`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Interpolation {
    /// Straight lines between keyframes, at constant speed.
    #[default]
    Linear,
    /// A cubic Hermite spline through the keyframes whose tangents are Catmull-Rom's over the
    /// keyframes' frame numbers; end tangents along the end segments (docs/camera.md).
    CatmullRom,
}

impl<'de> Deserialize<'de> for Interpolation {
    /// From its name, `"linear"` or `"catmull-rom"`. (serde's derived form also reads a table,
    /// and said of a number only "wanted string or table".)
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Name;
        impl serde::de::Visitor<'_> for Name {
            type Value = Interpolation;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("\"linear\" or \"catmull-rom\"")
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Interpolation, E> {
                match v {
                    "linear" => Ok(Interpolation::Linear),
                    "catmull-rom" => Ok(Interpolation::CatmullRom),
                    _ => Err(E::custom(format_args!(
                        "unknown interpolation \"{v}\", expected \"linear\" or \"catmull-rom\""
                    ))),
                }
            }
        }
        d.deserialize_str(Name)
    }
}

/// Keyframes (position, look-at, up, fov) interpolated over the frames.
#[derive(Clone, Debug)]
pub struct CameraPath {
    pub keyframes: Vec<Keyframe>,
    pub interpolation: Interpolation,
}

impl CameraPath {
    /// The keyframe of `frame`: a keyframe's own at its frame, the last one's after it.
    pub fn at(&self, frame: u32) -> Keyframe {
        match self.interpolation {
            Interpolation::Linear => self.linear(frame),
            Interpolation::CatmullRom => self.catmull_rom(frame),
        }
    }

    fn linear(&self, frame: u32) -> Keyframe {
        let ks = &self.keyframes;
        let i = ks.partition_point(|k| k.frame <= frame).saturating_sub(1);
        let a = &ks[i];
        let Some(b) = ks.get(i + 1) else {
            return Keyframe { frame, ..a.clone() };
        };
        let t = (frame - a.frame) as f32 / (b.frame - a.frame) as f32;
        Keyframe {
            frame,
            position: a.position.lerp(b.position, t),
            look_at: a.look_at.lerp(b.look_at, t),
            up: a.up.lerp(b.up, t),
            fov: a.fov + (b.fov - a.fov) * t,
        }
    }

    /// The spline's keyframe at `frame`: a keyframe's own at its frame (exactly: no rounding of
    /// zero weights), the last one's after it.
    fn catmull_rom(&self, frame: u32) -> Keyframe {
        let ks = &self.keyframes;
        let i = ks.partition_point(|k| k.frame <= frame).saturating_sub(1);
        if ks[i].frame == frame || i + 1 == ks.len() {
            return Keyframe {
                frame,
                ..ks[i].clone()
            };
        }
        let v = self.spline(frame as f64);
        let v3 = |c: usize| DVec3::new(v[c], v[c + 1], v[c + 2]).as_vec3();
        Keyframe {
            frame,
            position: v3(0),
            look_at: v3(3),
            up: v3(6),
            fov: v[9] as f32,
        }
    }

    /// The spline at time `t` in frames (not only whole frames: the tests differentiate it), in
    /// f64, for each of the ten numbers of a keyframe (position, look-at, up, fov) on its own.
    /// docs/camera.md derives it: on the segment from keyframe `i` to `i+1`, `h` frames long,
    /// `s = (t - t_i) / h`, `P(s) = h00(s) P_i + h10(s) h m_i + h01(s) P_i+1 + h11(s) h m_i+1`
    /// (cubic Hermite), where the tangent `m_i` (per frame) is the slopes of the segments either
    /// side weighted by the length of the other one (Catmull-Rom over the frame numbers), and,
    /// at the first and last keyframes, the slope of the end segment.
    fn spline(&self, t: f64) -> [f64; 10] {
        let ks = &self.keyframes;
        let i = ks
            .partition_point(|k| k.frame as f64 <= t)
            .saturating_sub(1);
        let Some(b) = ks.get(i + 1) else {
            return values(&ks[i]);
        };
        let a = &ks[i];
        let slope = |j: usize| -> [f64; 10] {
            let (p, q) = (values(&ks[j]), values(&ks[j + 1]));
            let h = (ks[j + 1].frame - ks[j].frame) as f64;
            std::array::from_fn(|c| (q[c] - p[c]) / h)
        };
        let tangent = |j: usize| -> [f64; 10] {
            if j == 0 {
                return slope(0);
            }
            if j + 1 == ks.len() {
                return slope(j - 1);
            }
            let (d0, d1) = (slope(j - 1), slope(j));
            let h0 = (ks[j].frame - ks[j - 1].frame) as f64;
            let h1 = (ks[j + 1].frame - ks[j].frame) as f64;
            std::array::from_fn(|c| (h1 * d0[c] + h0 * d1[c]) / (h0 + h1))
        };
        let h = (b.frame - a.frame) as f64;
        let s = (t - a.frame as f64) / h;
        let (s2, s3) = (s * s, s * s * s);
        let (h00, h10, h01, h11) = (
            2.0 * s3 - 3.0 * s2 + 1.0,
            s3 - 2.0 * s2 + s,
            -2.0 * s3 + 3.0 * s2,
            s3 - s2,
        );
        let (pa, pb, ma, mb) = (values(a), values(b), tangent(i), tangent(i + 1));
        std::array::from_fn(|c| h00 * pa[c] + h10 * h * ma[c] + h01 * pb[c] + h11 * h * mb[c])
    }
}

/// A keyframe's numbers, as the spline interpolates them: position, look-at, up, fov.
fn values(k: &Keyframe) -> [f64; 10] {
    let (p, l, u) = (k.position, k.look_at, k.up);
    [p.x, p.y, p.z, l.x, l.y, l.z, u.x, u.y, u.z, k.fov].map(|v| v as f64)
}

/// The cameras of a scene's frames: keyframes interpolated, or one pose per frame.
#[derive(Clone, Debug)]
pub enum Cameras {
    /// `[[keyframe]]` tables of the scene TOML.
    Path(CameraPath),
    /// A camera file's poses, frame `i` at index `i`.
    PerFrame(Vec<Pose>),
}

impl Cameras {
    /// The pose of `frame` (past the last frame: the last one's).
    pub fn pose(&self, frame: u32) -> Pose {
        match self {
            Cameras::Path(p) => p.at(frame).pose(),
            Cameras::PerFrame(v) => v[(frame as usize).min(v.len() - 1)].clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        let k = Keyframe {
            frame: 0,
            position: Vec3::new(1.0, 2.0, 3.0),
            look_at: Vec3::new(0.0, 0.5, -1.0),
            up: Vec3::Y,
            fov: 50.0,
        };
        Camera::new(&k, 80, 60)
    }

    #[test]
    fn a_tiny_up_or_view_makes_the_camera_a_unit_one_does() {
        // An up of 1e-19 (its cross product with the view has a squared length below the
        // smallest normal float) made the axes NaN and every frame black; a view of 3e-7 was
        // refused as coinciding with the position.
        let pose = |view: Vec3, up: Vec3| Pose {
            eye: Vec3::new(0.0, 1.0e-7, 3.0e-7),
            view,
            up,
            fov: 50.0,
        };
        let view = Vec3::new(0.0, -1.0e-7, -3.0e-7);
        let unit_up = Camera::from_pose(&pose(view, Vec3::Y), 80, 60);
        for up in [Vec3::Y * 1.0e-19, Vec3::Y * 1.0e-30, Vec3::Y * 1.0e30] {
            assert_eq!(pose(view, up).fault(), None, "{up}");
            let c = Camera::from_pose(&pose(view, up), 80, 60);
            for (a, b) in [
                (c.forward, unit_up.forward),
                (c.right, unit_up.right),
                (c.up, unit_up.up),
            ] {
                assert!((a - b).length() < 1e-6, "{up}: {a} against {b}");
            }
        }
        let far = Camera::from_pose(&pose(view * 1.0e7, Vec3::Y), 80, 60);
        assert!((far.forward - unit_up.forward).length() < 1e-6);
        // Refused: length zero, and a vector of subnormal components (1e-44), which the
        // render's threads flush to zero (its axes came out NaN there, every frame black).
        assert!(pose(view, Vec3::Y * 1.0e-44)
            .fault()
            .unwrap()
            .contains("shorter than the render's arithmetic resolves"));
        assert!(pose(view * 1.0e-33, Vec3::Y)
            .fault()
            .unwrap()
            .contains("closer than the render's arithmetic resolves"));
        assert!(pose(Vec3::ZERO, Vec3::Y)
            .fault()
            .unwrap()
            .contains("coincides"));
        assert!(pose(view, Vec3::ZERO)
            .fault()
            .unwrap()
            .contains("zero length"));
        assert!(pose(view, view * 2.0).fault().unwrap().contains("parallel"));
    }

    #[test]
    fn project_inverts_direction() {
        let c = cam();
        for (x, y) in [(0.5, 0.5), (40.0, 30.0), (79.5, 12.25), (3.0, 59.0)] {
            let r = Vec2::new(x, y);
            let p = c.eye + c.direction(r) * 4.2;
            let back = c.project(p).unwrap();
            assert!((back - r).length() < 1e-3, "{r} -> {back}");
        }
        assert!(c.project(c.eye - c.forward).is_none(), "behind the eye");
    }

    #[test]
    fn matrices_agree_with_project() {
        let c = cam();
        let p = c.eye + c.direction(Vec2::new(20.0, 45.0)) * 3.0;
        let cs = c.world_to_camera().transform_point3(p);
        assert!(cs.z > 0.0 && cs.x < 0.0 && cs.y < 0.0, "{cs}");
        let ndc = c.world_to_ndc() * p.extend(1.0);
        let ndc = Vec2::new(ndc.x / ndc.w, ndc.y / ndc.w);
        assert!(
            (ndc - Vec2::new(20.0 / 80.0, 45.0 / 60.0)).length() < 1e-4,
            "{ndc}"
        );
    }

    /// The Jacobian is the ratio of film area to surface area: a small patch facing the eye at
    /// distance d on the axis covers f^2/d^2 of its area on the film.
    #[test]
    fn jacobian_matches_projected_area() {
        let c = cam();
        // An oblique patch off-axis: compare J with the film area of its projection.
        let x = c.eye + c.direction(Vec2::new(60.0, 10.0)) * 3.0;
        let n = Vec3::new(0.3, 0.8, 0.2).normalize();
        let (t, b) = crate::sampling::basis(n);
        let h = 1e-3;
        let film = |p: Vec3| {
            let r = c.project(p).unwrap();
            // raster -> film coordinates at f = 1
            Vec2::new(r.x / c.width as f32, r.y / c.height as f32)
                * Vec2::new(2.0 * c.tan_half_fov * c.aspect, 2.0 * c.tan_half_fov)
        };
        let (p0, p1, p2) = (film(x), film(x + t * h), film(x + b * h));
        let e1 = p1 - p0;
        let e2 = p2 - p0;
        let area_film = (e1.x * e2.y - e1.y * e2.x).abs();
        let j = c.jacobian(x, n);
        assert!(
            (area_film / (h * h) / j - 1.0).abs() < 0.01,
            "{} vs {}",
            area_film / (h * h),
            j
        );
    }

    #[test]
    fn path_interpolates() {
        let k0 = Keyframe {
            frame: 0,
            position: Vec3::ZERO,
            look_at: Vec3::Z,
            up: Vec3::Y,
            fov: 40.0,
        };
        let k1 = Keyframe {
            frame: 10,
            position: Vec3::X,
            look_at: Vec3::Z,
            up: Vec3::Y,
            fov: 20.0,
        };
        let p = CameraPath {
            keyframes: vec![k0, k1],
            interpolation: Interpolation::Linear,
        };
        let m = p.at(5);
        assert!((m.position.x - 0.5).abs() < 1e-6 && (m.fov - 30.0).abs() < 1e-5);
        assert_eq!(p.at(10).position, Vec3::X);
        assert_eq!(p.at(12).position, Vec3::X);
    }

    /// Three keyframes that turn a corner (position and fov change speed at frame 4).
    fn corner(interpolation: Interpolation) -> CameraPath {
        let k = |frame, position: Vec3, fov| Keyframe {
            frame,
            position,
            look_at: Vec3::new(0.0, 0.0, -5.0),
            up: Vec3::Y,
            fov,
        };
        CameraPath {
            keyframes: vec![
                k(0, Vec3::ZERO, 40.0),
                k(4, Vec3::new(2.0, 0.0, 0.0), 50.0),
                k(14, Vec3::new(2.0, 3.0, 1.0), 30.0),
                k(20, Vec3::new(-1.0, 3.0, 0.0), 30.0),
            ],
            interpolation,
        }
    }

    #[test]
    fn catmull_rom_passes_through_every_keyframe_exactly() {
        let p = corner(Interpolation::CatmullRom);
        for k in &p.keyframes {
            assert_eq!(&p.at(k.frame), k);
        }
        assert_eq!(
            p.at(25),
            Keyframe {
                frame: 25,
                ..p.keyframes[3].clone()
            }
        );
        // Between keyframes it is not the polyline.
        let lin = corner(Interpolation::Linear);
        assert!((p.at(9).position - lin.at(9).position).length() > 0.1);
    }

    /// Velocity (per frame) left and right of `t`, by finite differences of the spline.
    fn velocities(p: &CameraPath, t: f64) -> ([f64; 10], [f64; 10]) {
        let e = 1e-4;
        let (l, m, r) = (p.spline(t - e), p.spline(t), p.spline(t + e));
        (
            std::array::from_fn(|c| (m[c] - l[c]) / e),
            std::array::from_fn(|c| (r[c] - m[c]) / e),
        )
    }

    #[test]
    fn catmull_rom_is_c1_across_keyframes() {
        let p = corner(Interpolation::CatmullRom);
        for k in &p.keyframes[1..3] {
            let (l, r) = velocities(&p, k.frame as f64);
            for c in 0..10 {
                // The second derivative is at most a few units per frame^2 here: over 1e-4
                // frames the two one-sided differences move apart by less than 1e-3.
                assert!(
                    (l[c] - r[c]).abs() < 1e-3,
                    "frame {}: {l:?} vs {r:?}",
                    k.frame
                );
            }
            // The tangent is the two neighbouring slopes weighted by the other segment's length.
            let ks = &p.keyframes;
            let j = ks.iter().position(|x| x.frame == k.frame).unwrap();
            let (h0, h1) = (
                (ks[j].frame - ks[j - 1].frame) as f64,
                (ks[j + 1].frame - ks[j].frame) as f64,
            );
            let d0 = (ks[j].fov - ks[j - 1].fov) as f64 / h0;
            let d1 = (ks[j + 1].fov - ks[j].fov) as f64 / h1;
            let m = (h1 * d0 + h0 * d1) / (h0 + h1);
            assert!((r[9] - m).abs() < 1e-3, "fov tangent {} vs {m}", r[9]);
        }
        // The same check fails for the linear path: its velocity jumps at the keyframes (by
        // 0.5 per frame in x at frame 4).
        let lin = corner(Interpolation::Linear);
        let v = |t: u32| lin.at(t + 1).position - lin.at(t).position;
        assert!((v(4) - v(3)).length() > 0.4);
    }

    #[test]
    fn catmull_rom_of_two_keyframes_is_linear() {
        // The end tangents are the end segments' slopes: with one segment, a straight line at
        // constant speed (within rounding: the spline is evaluated in f64).
        let mut p = corner(Interpolation::CatmullRom);
        p.keyframes.truncate(2);
        let mut lin = p.clone();
        lin.interpolation = Interpolation::Linear;
        for f in 0..=6 {
            let (a, b) = (p.at(f), lin.at(f));
            assert!((a.position - b.position).length() < 1e-6, "frame {f}");
            assert!((a.fov - b.fov).abs() < 1e-5, "frame {f}");
        }
        // With a third keyframe the first segment bends towards it.
        let three = corner(Interpolation::CatmullRom);
        assert!((three.at(2).position - lin.at(2).position).length() > 0.05);
    }

    #[test]
    fn a_camera_to_world_matrix_gives_the_look_at_camera() {
        let c = cam();
        // Blender's convention: columns right, up, back (-forward), eye; scaled by 2.5.
        let (r, u, b, e) = (c.right * 2.5, c.up * 2.5, -c.forward * 2.5, c.eye);
        let m = [
            r.x, u.x, b.x, e.x, r.y, u.y, b.y, e.y, r.z, u.z, b.z, e.z, 0.0, 0.0, 0.0, 1.0,
        ]
        .map(|v| v as f64);
        let d = Camera::from_pose(&Pose::from_camera_to_world(&m, 50.0), 80, 60);
        for (x, y) in [(d.forward, c.forward), (d.right, c.right), (d.up, c.up)] {
            assert!((x - y).length() < 1e-6, "{x} vs {y}");
        }
        assert_eq!(d.eye, c.eye);
        assert_eq!(d.tan_half_fov, c.tan_half_fov);
    }
}
