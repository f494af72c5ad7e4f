//! Pinhole cameras and the camera path of an animation.
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
use glam::{Mat4, Vec2, Vec3, Vec4};

/// One camera keyframe of a scene file (fov: vertical, in degrees).
#[derive(Clone, Debug, PartialEq)]
pub struct Keyframe {
    pub frame: u32,
    pub position: Vec3,
    pub look_at: Vec3,
    pub up: Vec3,
    pub fov: f32,
}

#[derive(Clone, Debug)]
pub struct Camera {
    pub eye: Vec3,
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
        let forward = (k.look_at - k.position).normalize();
        let right = forward.cross(k.up).normalize();
        let up = right.cross(forward);
        Camera {
            eye: k.position,
            forward,
            right,
            up,
            tan_half_fov: (k.fov.to_radians() * 0.5).tan(),
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
        let c = x - self.eye;
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
    /// (x right, y up, z the viewing direction), as a column-vector matrix.
    pub fn world_to_camera(&self) -> Mat4 {
        let e = self.eye;
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

/// Keyframes interpolated linearly (position, look-at, up, fov) over the frames.
#[derive(Clone, Debug)]
pub struct CameraPath {
    pub keyframes: Vec<Keyframe>,
}

impl CameraPath {
    pub fn at(&self, frame: u32) -> Keyframe {
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
        };
        let m = p.at(5);
        assert!((m.position.x - 0.5).abs() < 1e-6 && (m.fov - 30.0).abs() < 1e-5);
        assert_eq!(p.at(10).position, Vec3::X);
        assert_eq!(p.at(12).position, Vec3::X);
    }
}
