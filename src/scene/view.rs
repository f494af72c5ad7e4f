//! Whether the cameras see the scene at all: a camera whose view misses every object renders a
//! black frame, or one of the environment alone, without an error anywhere. Cameras written in
//! another package's conventions (one whose cameras look down +Z, not -Z), in other units, or
//! pointed backwards do that, and the render takes its full time to show it.
use super::{box_corners, world_bounds, Scene};
use crate::camera::Camera;
use glam::Vec3;
use std::ops::RangeInclusive;

/// Whether the view of `cam` surely misses the box `lo`-`hi`: every corner of the box lies
/// behind the eye, or beyond one side of the view's pyramid (each a half-space, so a box whose
/// corners are all outside one of them is outside it whole). Conservative: a box that the
/// pyramid misses only past its corners (beside one of its edges) counts as seen.
fn misses(cam: &Camera, lo: Vec3, hi: Vec3) -> bool {
    let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
    let ty = cam.tan_half_fov as f64;
    let tx = ty * cam.aspect as f64;
    let eye = cam.eye.as_dvec3();
    let (f, r, u) = (
        cam.forward.as_dvec3(),
        cam.right.as_dvec3(),
        cam.up.as_dvec3(),
    );
    // Per side: how far each corner is outside it (positive: outside), against a tolerance of
    // the terms' rounding, so that a box touching a side counts as seen.
    let mut outside = [true; 5];
    for c in box_corners(lo, hi) {
        let d = c - eye;
        let (z, x, y) = (d.dot(f), d.dot(r), d.dot(u));
        let tol = 1e-6 * d.length();
        let sides = [-z, x - z * tx, -x - z * tx, y - z * ty, -y - z * ty];
        for (o, s) in outside.iter_mut().zip(sides) {
            *o &= s > tol;
        }
    }
    outside.contains(&true)
}

impl Scene {
    /// The frames of `frames` whose camera (at `width` x `height`) surely misses the box around
    /// the scene's geometry (`misses`); none where it has none.
    pub fn missed_frames(
        &self,
        frames: RangeInclusive<u32>,
        (width, height): (u32, u32),
    ) -> Vec<u32> {
        let (lo, hi) = world_bounds(&self.positions, &self.prototypes, &self.instances);
        if lo.x > hi.x {
            return Vec::new();
        }
        frames
            .filter(|&f| misses(&self.camera(f, width, height), lo, hi))
            .collect()
    }

    /// A warning where the cameras of `missed` (`missed_frames`, of a render of `total` frames)
    /// see none of the scene's geometry: any such frame when the scene has no environment (it
    /// would be black), every frame when it has one (a shot that turns to the sky for a while is
    /// fine; one that never sees the scene is most likely a camera in the wrong axes or units).
    pub fn unseen_frames(&self, missed: &[u32], total: usize) -> Option<String> {
        let (lo, hi) = world_bounds(&self.positions, &self.prototypes, &self.instances);
        let environment = self.environment.is_some();
        if missed.is_empty() || (environment && missed.len() < total) {
            return None;
        }
        let (wlo, whi) = (lo.as_dvec3() + self.origin, hi.as_dvec3() + self.origin);
        let which = if missed.len() == total {
            format!(
                "every frame of the render ({})",
                crate::util::text::ranges(missed, 4)
            )
        } else {
            format!(
                "frame(s) {} ({} of {total})",
                crate::util::text::ranges(missed, 4),
                missed.len()
            )
        };
        let what = if environment {
            "they show the environment alone"
        } else {
            "with no environment, they are black"
        };
        // The scene file (a shipped scene by its name): where the camera is written.
        let label = self
            .inputs
            .first()
            .map_or_else(|| self.name.clone(), |p| p.display().to_string());
        Some(format!(
            "{label}: the camera of {which} sees none of the scene's geometry (its view misses the box \
             from {:.4?} to {:.4?} around it): {what}; check the camera's position, units and \
             axes (a camera file from a package whose cameras look down +Z looks backwards here)",
            wlo.to_array(),
            whi.to_array()
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Keyframe, Pose};

    fn camera(eye: [f32; 3], look_at: [f32; 3], fov: f32, (w, h): (u32, u32)) -> Camera {
        let k = Keyframe {
            frame: 0,
            position: Vec3::from(eye),
            look_at: Vec3::from(look_at),
            up: Vec3::Y,
            fov,
        };
        let p: Pose = k.pose();
        Camera::from_pose(&p, w, h)
    }

    #[test]
    fn a_box_is_missed_only_where_the_view_surely_misses_it() {
        let (lo, hi) = (Vec3::splat(-1.0), Vec3::splat(1.0));
        let at = |eye, look, fov, size| misses(&camera(eye, look, fov, size), lo, hi);
        // Looking at it, from outside and from inside.
        assert!(!at([0.0, 0.0, 5.0], [0.0, 0.0, 0.0], 40.0, (64, 48)));
        assert!(!at([0.5, 0.2, 0.1], [0.0, 0.0, -9.0], 10.0, (64, 48)));
        // Looking away from it, and past it to either side, above and below.
        assert!(at([0.0, 0.0, 5.0], [0.0, 0.0, 10.0], 40.0, (64, 48)));
        assert!(at([0.0, 0.0, 5.0], [6.0, 0.0, 4.0], 40.0, (64, 48)));
        assert!(at([0.0, 0.0, 5.0], [-6.0, 0.0, 4.0], 40.0, (64, 48)));
        assert!(at([0.0, 0.0, 5.0], [0.0, 6.0, 4.0], 40.0, (64, 48)));
        assert!(at([0.0, 0.0, 5.0], [0.0, -6.0, 4.0], 40.0, (64, 48)));
        // The same turn seen by a wide enough view (a wider fov or film) sees its edge.
        assert!(!at([0.0, 0.0, 5.0], [6.0, 0.0, 4.0], 150.0, (64, 48)));
        assert!(!at([0.0, 0.0, 5.0], [2.0, 0.0, 4.0], 20.0, (400, 48)));
        assert!(at([0.0, 0.0, 5.0], [2.0, 0.0, 4.0], 20.0, (48, 48)));
        // A box whose far top edge lies on the bottom side of the view (looking level from
        // above it) counts as seen; a hundredth higher, it is missed.
        let t = (20.0f32).to_radians().tan();
        let y = 1.0 + 6.0 * t;
        assert!(!at([0.0, y, 5.0], [0.0, y, 0.0], 40.0, (48, 48)));
        assert!(at(
            [0.0, y + 0.01, 5.0],
            [0.0, y + 0.01, 0.0],
            40.0,
            (48, 48)
        ));
    }

    #[test]
    fn frames_are_said_as_runs() {
        assert_eq!(
            crate::util::text::ranges(&[0, 1, 2, 3, 7, 9, 10], 4),
            "0-3, 7, 9-10"
        );
        assert_eq!(
            crate::util::text::ranges(&[1, 3, 5, 7, 9, 11], 4),
            "1, 3, 5, 7, and 2 more run(s)"
        );
        assert_eq!(crate::util::text::ranges(&[4], 4), "4");
    }
}
