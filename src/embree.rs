//! The Embree 4 layer: the only module of reframe with `unsafe` code (besides the cxx bridge).
//!
//! It owns the Embree device and the committed scene (both released on `Drop`), turns Embree's
//! errors into Rust errors through the device error callback, and enforces the Embree 4 calling
//! invariants in one place so that no call site can get them wrong:
//! 16-byte (single) and 64-byte (packet) aligned ray structs, `geomID` set to
//! `RTC_INVALID_GEOMETRY_ID` before every intersect call, an explicit ray mask, and `tnear`/origin
//! offsets against self-intersection (`Ray::spawn`, `Ray::between`).
//!
//! ```no_run
//! use reframe::embree::{Device, Ray, TriangleScene};
//! use glam::Vec3;
//! let device = Device::new()?;
//! let scene = TriangleScene::new(&device, &[Vec3::ZERO, Vec3::X, Vec3::Y], &[[0, 1, 2]])?;
//! let hit = scene.intersect1(&Ray::new(Vec3::new(0.2, 0.2, 1.0), -Vec3::Z));
//! assert_eq!(hit.unwrap().prim_id, 0);
//! # anyhow::Ok(())
//! ```
//!
//! ABI note: `embree4-sys` 0.0.12 generates its bindings from Embree 4.2 headers, while the
//! runtime reframe ships is Embree 4.4, built with instance arrays. That build has an extra
//! `instPrimID` field at the end of `RTCHit`/`RTCHit16` (and of `RTCRayQueryContext`), which the
//! 4.2 layout lacks. So every ray-hit struct handed to Embree here carries trailing padding that
//! absorbs that write, and the query context is left null so that Embree builds its own default.
use anyhow::{anyhow, bail, Result};
use embree4_sys as sys;
use glam::Vec3;
use std::ffi::{c_char, c_void, CStr};
use std::ptr;
use std::sync::{Arc, Mutex};

/// `RTC_INVALID_GEOMETRY_ID` (a `#define` that bindgen does not carry over).
const INVALID_ID: u32 = u32::MAX;
/// All of reframe's geometry lives in mask bit 0; rays test against every bit explicitly
/// (Embree 4's default geometry mask is 1, and a zero ray mask would hit nothing).
const RAY_MASK: u32 = u32::MAX;

/// Where the error callback leaves Embree's messages until the wrapper reads them.
struct ErrorSink(Mutex<Vec<String>>);

unsafe extern "C" fn error_callback(user: *mut c_void, code: sys::RTCError, msg: *const c_char) {
    // SAFETY: `user` is the `ErrorSink` boxed in `Device`, alive as long as the device is.
    let sink = unsafe { &*(user as *const ErrorSink) };
    let text = if msg.is_null() {
        String::new()
    } else {
        // SAFETY: Embree passes a NUL-terminated string valid for the duration of the call.
        unsafe { CStr::from_ptr(msg) }
            .to_string_lossy()
            .into_owned()
    };
    if let Ok(mut v) = sink.0.lock() {
        v.push(format!("Embree error {code:?}: {text}"));
    }
}

/// An Embree device. Owns the handle and the error sink the callback writes to.
pub struct Device {
    raw: sys::RTCDevice,
    errors: Box<ErrorSink>,
}

impl Device {
    pub fn new() -> Result<Device> {
        // SAFETY: a null config string asks for the defaults.
        let raw = unsafe { sys::rtcNewDevice(ptr::null()) };
        if raw.is_null() {
            // SAFETY: the null device reports the error of the failed creation.
            let code = unsafe { sys::rtcGetDeviceError(ptr::null_mut()) };
            bail!(
                "could not create the Embree device ({code:?}){}",
                crate::util::mem::address_space_note()
            );
        }
        let errors = Box::new(ErrorSink(Mutex::new(Vec::new())));
        let user = &*errors as *const ErrorSink as *mut c_void;
        // SAFETY: the sink is boxed, so its address is stable, and it outlives the device.
        unsafe { sys::rtcSetDeviceErrorFunction(raw, Some(error_callback), user) };
        let device = Device { raw, errors };
        // The hit structs are laid out for Embree 4 with one instance level (see the module
        // note); another major version would write elsewhere.
        let v = device.version();
        if !(40000..50000).contains(&v) {
            bail!(
                "the Embree runtime is version {}.{}.{}; reframe needs Embree 4",
                v / 10000,
                v / 100 % 100,
                v % 100
            );
        }
        Ok(device)
    }

    /// The runtime's version as a number, e.g. 40400 for Embree 4.4.0.
    pub fn version(&self) -> i64 {
        // SAFETY: valid device handle.
        unsafe { sys::rtcGetDeviceProperty(self.raw, sys::RTCDeviceProperty::VERSION) as i64 }
    }

    /// Turn whatever the callback collected since the last check into an error.
    fn check(&self, what: &str) -> Result<()> {
        let mut v = self
            .errors
            .0
            .lock()
            .map_err(|_| anyhow!("Embree error sink poisoned"))?;
        if v.is_empty() {
            return Ok(());
        }
        let msg = v.join("; ");
        v.clear();
        Err(anyhow!(
            "{what}: {msg}{}",
            crate::util::mem::address_space_note()
        ))
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        // SAFETY: the handle is valid and released once; scenes hold their own reference.
        unsafe { sys::rtcReleaseDevice(self.raw) };
    }
}

/// A ray: origin, direction (unit, except in `Ray::between`'s occlusion segments), and the
/// parametric interval `[tnear, tfar]`.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    pub org: Vec3,
    pub dir: Vec3,
    pub tnear: f32,
    pub tfar: f32,
}

/// Relative offset applied to origins on surfaces: Embree's watertight triangle test is accurate
/// to a few ulps of the coordinates, and 64 ulps of the largest coordinate clears that.
pub(crate) const SPAWN_EPS: f32 = 64.0 * f32::EPSILON;

/// `p` moved off its surface (geometric normal `ng`) to the side of `toward`, by
/// `SPAWN_EPS (floor + max |p|)`. `floor` (`Scene::offset_floor`) keeps the offset above rounding
/// near the origin: 1, or the scene's size where that is smaller, so that a scene modelled at a
/// tiny scale keeps contact shadows thinner than `SPAWN_EPS` units.
fn offset_origin(p: Vec3, ng: Vec3, toward: Vec3, floor: f32) -> Vec3 {
    let scale = SPAWN_EPS * (floor + p.abs().max_element());
    let n = if ng.dot(toward) >= 0.0 { ng } else { -ng };
    p + n * scale
}

impl Ray {
    pub fn new(org: Vec3, dir: Vec3) -> Ray {
        Ray {
            org,
            dir,
            tnear: 0.0,
            tfar: f32::INFINITY,
        }
    }

    /// A ray leaving surface point `p` (geometric normal `ng`) in direction `dir`, with the
    /// origin pushed off the surface to the side `dir` goes to, so it cannot hit its own triangle.
    pub fn spawn(p: Vec3, ng: Vec3, dir: Vec3, floor: f32) -> Ray {
        Ray::new(offset_origin(p, ng, dir, floor), dir)
    }

    /// A shadow/visibility ray between two points, each offset off its own surface (pass a zero
    /// normal for a point that is not on a surface, e.g. a pinhole eye), for occlusion tests
    /// only: the direction is the segment itself, not a unit vector (Embree takes any
    /// direction), so `t` runs from 0 at `p0` to 1 at `p1` and `tfar` stops short of `p1`'s
    /// surface. Leaving out the normalisation saves a square root and a division, whose latency
    /// was a tenth of a reuse render's time (one such ray per reuse).
    pub fn between(p0: Vec3, n0: Vec3, p1: Vec3, n1: Vec3, floor: f32) -> Ray {
        let d = p1 - p0;
        let o0 = offset_origin(p0, n0, d, floor);
        let o1 = offset_origin(p1, n1, -d, floor);
        Ray {
            org: o0,
            dir: o1 - o0,
            tnear: 0.0,
            tfar: 1.0 - SPAWN_EPS,
        }
    }

    /// `between(eye, Vec3::ZERO, p1, n1)`, bit for bit, for a point that is not on a surface
    /// (a pinhole eye; the reuse visibility tests): its origin needs no offset.
    #[inline]
    pub fn from_eye(eye: Vec3, p1: Vec3, n1: Vec3, floor: f32) -> Ray {
        let o1 = offset_origin(p1, n1, eye - p1, floor);
        Ray::from_eye_dir(eye, o1 - eye)
    }

    /// `from_eye` with its direction already made: the segment from the eye to the point
    /// offset off its surface.
    #[inline]
    pub fn from_eye_dir(eye: Vec3, dir: Vec3) -> Ray {
        Ray {
            org: eye,
            dir,
            tnear: 0.0,
            tfar: 1.0 - SPAWN_EPS,
        }
    }
}

/// The minimal hit that the integrator builds shading data from (Mitsuba's preliminary
/// intersection): distance, triangle, barycentrics, unnormalised geometric normal.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f32,
    /// The instance hit (`TriangleScene::build`'s index), or `NO_INSTANCE` for the scene's own
    /// triangles.
    pub inst: u32,
    /// The triangle: of the scene's own mesh, or of the instance's prototype.
    pub prim_id: u32,
    pub u: f32,
    pub v: f32,
    pub ng: Vec3,
}

impl Hit {
    pub const NO_INSTANCE: u32 = INVALID_ID;
}

/// `RTCRayHit` plus room for the 4.4 runtime's `instPrimID` (see the module note).
#[repr(C, align(16))]
struct RayHit1 {
    rh: sys::RTCRayHit,
    _pad: [u32; 4],
}

/// `RTCRayHit16` plus room for the 4.4 runtime's `instPrimID[16]`.
#[repr(C, align(64))]
struct RayHit16 {
    rh: sys::RTCRayHit16,
    _pad: [u32; 16],
}

/// The packet's lane mask; Embree loads it as one 64-byte vector, so it must be aligned like one.
#[repr(C, align(64))]
#[derive(Clone, Copy)]
struct Valid16([i32; 16]);

impl std::ops::Deref for Valid16 {
    type Target = [i32; 16];
    fn deref(&self) -> &[i32; 16] {
        &self.0
    }
}

impl std::ops::DerefMut for Valid16 {
    fn deref_mut(&mut self) -> &mut [i32; 16] {
        &mut self.0
    }
}

/// Sixteen rays in structure-of-arrays form, for coherent batches (primary rays, and the
/// visibility tests of reuse that all converge on one eye). Fill with `set`, leave unused lanes
/// inactive; after `intersect16`/`occluded16` read the results per lane.
pub struct Packet16 {
    raw: Box<RayHit16>,
    active: Valid16,
    occluded: [bool; 16],
}

impl Default for Packet16 {
    fn default() -> Self {
        Self::new()
    }
}

impl Packet16 {
    pub fn new() -> Packet16 {
        // SAFETY: RTCRayHit16 is plain old data; all-zero is a valid bit pattern.
        let mut raw: Box<RayHit16> = Box::new(unsafe { std::mem::zeroed() });
        // What `set` leaves as it is: the same for every ray (time 0 and flags 0 from zeroing).
        let r = &mut raw.rh.ray;
        r.mask = [RAY_MASK; 16];
        r.id = std::array::from_fn(|lane| lane as u32);
        Packet16 {
            raw,
            active: Valid16([0; 16]),
            occluded: [false; 16],
        }
    }

    /// Bytes one packet holds, its rays and hits included.
    pub const fn bytes() -> usize {
        std::mem::size_of::<Packet16>() + std::mem::size_of::<RayHit16>()
    }

    /// Deactivate all lanes.
    pub fn clear(&mut self) {
        self.active = Valid16([0; 16]);
    }

    pub fn set(&mut self, lane: usize, ray: &Ray) {
        let r = &mut self.raw.rh.ray;
        r.org_x[lane] = ray.org.x;
        r.org_y[lane] = ray.org.y;
        r.org_z[lane] = ray.org.z;
        r.dir_x[lane] = ray.dir.x;
        r.dir_y[lane] = ray.dir.y;
        r.dir_z[lane] = ray.dir.z;
        r.tnear[lane] = ray.tnear;
        r.tfar[lane] = ray.tfar;
        self.raw.rh.hit.geomID[lane] = INVALID_ID;
        self.raw.rh.hit.instID[0][lane] = INVALID_ID;
        self.active[lane] = -1;
    }

    /// The ray set in `lane`.
    pub fn ray(&self, lane: usize) -> Ray {
        let r = &self.raw.rh.ray;
        Ray {
            org: Vec3::new(r.org_x[lane], r.org_y[lane], r.org_z[lane]),
            dir: Vec3::new(r.dir_x[lane], r.dir_y[lane], r.dir_z[lane]),
            tnear: r.tnear[lane],
            tfar: r.tfar[lane],
        }
    }

    /// The hit of `lane` after `intersect16`.
    pub fn hit(&self, lane: usize) -> Option<Hit> {
        let h = &self.raw.rh.hit;
        if self.active[lane] == 0 || h.geomID[lane] == INVALID_ID {
            return None;
        }
        Some(Hit {
            t: self.raw.rh.ray.tfar[lane],
            inst: instance(h.instID[0][lane]),
            prim_id: h.primID[lane],
            u: h.u[lane],
            v: h.v[lane],
            ng: Vec3::new(h.Ng_x[lane], h.Ng_y[lane], h.Ng_z[lane]),
        })
    }

    /// Whether `lane` was blocked, after `occluded16`.
    pub fn occluded(&self, lane: usize) -> bool {
        self.occluded[lane]
    }
}

/// A committed, immutable Embree scene: one triangle mesh of the scene's own (geometry 0), and
/// instances of prototype meshes placed by affine transforms (geometry `1 + i` for instance
/// `i`). Primitive IDs are the triangle indices of the mesh hit, the scene's own or the
/// instance's prototype; `Hit::inst` tells which.
pub struct TriangleScene {
    raw: sys::RTCScene,
    /// The prototypes' own scenes, which the instances reference.
    prototypes: Vec<sys::RTCScene>,
    device: sys::RTCDevice,
    /// The cut-out tests the geometries' filter functions call, boxed so that the address each
    /// geometry holds as its user data stays put for as long as the scene lives.
    #[allow(clippy::vec_box)]
    cutouts: Vec<Box<Arc<dyn Cutout>>>,
}

/// Where a mesh is cut out (an alpha mask): Embree asks `opaque` of every candidate hit on a
/// mesh that has one, by the triangle (`prim`, the mesh's own index) and the hit's barycentric
/// coordinates `(u, v)`, and goes on through the points where it answers `false`, for every
/// query: closest hits and occlusion, single rays and packets. The answer must be a function
/// of the point alone, so that every ray and every eye sees one surface.
pub trait Cutout: Send + Sync {
    fn opaque(&self, prim: u32, u: f32, v: f32) -> bool;
}

/// The cut-out tests of `TriangleScene::build`'s meshes: the scene's own and each prototype's
/// (`None`, or a shorter list: opaque).
#[derive(Default)]
pub struct Cutouts {
    pub own: Option<Arc<dyn Cutout>>,
    pub prototypes: Vec<Option<Arc<dyn Cutout>>>,
}

/// Embree's filter function for a geometry with a `Cutout` (the same for closest hits and for
/// occlusion): every valid candidate at a point the cut-out leaves out is made invalid, so
/// that traversal goes on past it.
unsafe extern "C" fn cutout_filter(args: *const sys::RTCFilterFunctionNArguments) {
    // SAFETY: Embree passes valid arguments for the duration of the call; the user data is the
    // `Arc<dyn Cutout>` boxed in `TriangleScene::cutouts`, alive as long as the scene. The hit
    // is `N` lanes of structure-of-arrays floats: `Ng_x`, `Ng_y`, `Ng_z`, `u`, `v`, `primID`
    // (Embree's `RTCHitN_u` etc.), the same in the 4.2 headers and the 4.4 runtime.
    unsafe {
        let args = &*args;
        let cut = &*(args.geometryUserPtr as *const Arc<dyn Cutout>);
        let n = args.N as usize;
        let hit = args.hit as *const f32;
        let valid = std::slice::from_raw_parts_mut(args.valid, n);
        for (i, valid) in valid.iter_mut().enumerate() {
            if *valid == 0 {
                continue;
            }
            let u = *hit.add(3 * n + i);
            let v = *hit.add(4 * n + i);
            let prim = *(hit as *const u32).add(5 * n + i);
            if !cut.opaque(prim, u, v) {
                *valid = 0;
            }
        }
    }
}

/// A mesh for `TriangleScene::build`: vertices and triangles.
pub type MeshRef<'a> = (&'a [Vec3], &'a [[u32; 3]]);

/// One placement of a prototype: its index and the object-to-world transform, a 3x4 matrix in
/// row-major order (the last column is the translation).
pub type Placement = (u32, [f32; 12]);

// SAFETY: a committed Embree scene is read-only and Embree documents rtcIntersect*/rtcOccluded*
// as thread-safe on it; `TriangleScene` exposes no way to modify it after `new` commits it.
unsafe impl Send for TriangleScene {}
unsafe impl Sync for TriangleScene {}

/// `instID[0]` of a hit as `Hit::inst`: the instance's index (its geometry ID less one).
#[inline]
fn instance(inst_geom: u32) -> u32 {
    if inst_geom == INVALID_ID {
        INVALID_ID
    } else {
        inst_geom - 1
    }
}

fn check_mesh((vertices, triangles): MeshRef) -> Result<()> {
    if triangles.is_empty() {
        bail!("the scene has no triangles");
    }
    let nv = vertices.len() as u32;
    if let Some(t) = triangles.iter().find(|t| t.iter().any(|&i| i >= nv)) {
        bail!("triangle {t:?} indexes past the {nv} vertices");
    }
    Ok(())
}

/// A committed triangle geometry of `mesh` (checked by `check_mesh`), cut out by the test at
/// `cutout` (kept alive by the caller as long as the geometry) where there is one; the caller
/// owns it.
fn triangle_geometry(
    device: &Device,
    (vertices, triangles): MeshRef,
    cutout: Option<&Arc<dyn Cutout>>,
) -> Result<sys::RTCGeometry> {
    // SAFETY: every handle is checked before use; buffers are sized from the slices and filled
    // before the geometry is committed.
    unsafe {
        let geom = sys::rtcNewGeometry(device.raw, sys::RTCGeometryType::TRIANGLE);
        device.check("creating the triangle geometry")?;
        let vb = sys::rtcSetNewGeometryBuffer(
            geom,
            sys::RTCBufferType::VERTEX,
            0,
            sys::RTCFormat::FLOAT3,
            12,
            vertices.len(),
        ) as *mut f32;
        let ib = sys::rtcSetNewGeometryBuffer(
            geom,
            sys::RTCBufferType::INDEX,
            0,
            sys::RTCFormat::UINT3,
            12,
            triangles.len(),
        ) as *mut u32;
        if let Err(e) = device.check("allocating geometry buffers") {
            sys::rtcReleaseGeometry(geom);
            return Err(e);
        }
        let vs = std::slice::from_raw_parts_mut(vb, vertices.len() * 3);
        for (i, v) in vertices.iter().enumerate() {
            vs[3 * i..3 * i + 3].copy_from_slice(&v.to_array());
        }
        let is = std::slice::from_raw_parts_mut(ib, triangles.len() * 3);
        for (i, t) in triangles.iter().enumerate() {
            is[3 * i..3 * i + 3].copy_from_slice(t);
        }
        if let Some(cut) = cutout {
            sys::rtcSetGeometryUserData(geom, cut as *const Arc<dyn Cutout> as *mut c_void);
            sys::rtcSetGeometryIntersectFilterFunction(geom, Some(cutout_filter));
            sys::rtcSetGeometryOccludedFilterFunction(geom, Some(cutout_filter));
        }
        sys::rtcCommitGeometry(geom);
        Ok(geom)
    }
}

impl TriangleScene {
    /// A scene of one mesh.
    pub fn new(device: &Device, vertices: &[Vec3], triangles: &[[u32; 3]]) -> Result<Self> {
        Self::build(
            device,
            Some((vertices, triangles)),
            &[],
            &[],
            Cutouts::default(),
        )
    }

    /// A scene of its own mesh `own` (if any) and `instances` of `prototypes`, each cut out
    /// where `cutouts` says. Each prototype is built once, however often it is placed.
    pub fn build(
        device: &Device,
        own: Option<MeshRef>,
        prototypes: &[MeshRef],
        instances: &[Placement],
        cutouts: Cutouts,
    ) -> Result<Self> {
        if own.is_none() && instances.is_empty() {
            bail!("the scene has no triangles");
        }
        if let Some(m) = own {
            check_mesh(m)?;
        }
        for m in prototypes {
            check_mesh(*m)?;
        }
        if let Some((p, _)) = instances.iter().find(|i| i.0 as usize >= prototypes.len()) {
            bail!("an instance of prototype {p} of {}", prototypes.len());
        }
        if let Some((_, m)) = instances
            .iter()
            .find(|i| !i.1.iter().all(|x| x.is_finite()))
        {
            bail!("an instance transform is not finite: {m:?}");
        }
        // SAFETY: every handle is checked before use; a scene retains what is attached to it,
        // so our own geometry references are released right after attaching; the prototype
        // scenes are kept (and released in `Drop`) for as long as the instances use them.
        unsafe {
            let scene = sys::rtcNewScene(device.raw);
            sys::rtcRetainDevice(device.raw);
            let mut s = TriangleScene {
                raw: scene,
                prototypes: Vec::with_capacity(prototypes.len()),
                device: device.raw,
                cutouts: Vec::new(),
            };
            // Boxed before any geometry takes its address.
            let mut keep = |c: Option<Arc<dyn Cutout>>| {
                c.map(|c| {
                    s.cutouts.push(Box::new(c));
                    s.cutouts.len() - 1
                })
            };
            let own_cut = keep(cutouts.own);
            let proto_cuts: Vec<Option<usize>> = (0..prototypes.len())
                .map(|i| keep(cutouts.prototypes.get(i).cloned().flatten()))
                .collect();
            for (m, cut) in prototypes.iter().zip(proto_cuts) {
                let geom = triangle_geometry(device, *m, cut.map(|c| &*s.cutouts[c]))?;
                let proto = sys::rtcNewScene(device.raw);
                sys::rtcSetSceneBuildQuality(proto, sys::RTCBuildQuality::HIGH);
                sys::rtcAttachGeometry(proto, geom);
                sys::rtcReleaseGeometry(geom);
                sys::rtcCommitScene(proto);
                s.prototypes.push(proto);
                if let Err(e) = device.check("building an instanced mesh") {
                    return Err(abandon(s, e));
                }
            }
            sys::rtcSetSceneBuildQuality(scene, sys::RTCBuildQuality::HIGH);
            if let Some(m) = own {
                let geom = triangle_geometry(device, m, own_cut.map(|c| &*s.cutouts[c]))?;
                sys::rtcAttachGeometryByID(scene, geom, 0);
                sys::rtcReleaseGeometry(geom);
            }
            for (i, (proto, xfm)) in instances.iter().enumerate() {
                let geom = sys::rtcNewGeometry(device.raw, sys::RTCGeometryType::INSTANCE);
                device.check("creating an instance")?;
                sys::rtcSetGeometryInstancedScene(geom, s.prototypes[*proto as usize]);
                sys::rtcSetGeometryTransform(
                    geom,
                    0,
                    sys::RTCFormat::FLOAT3X4_ROW_MAJOR,
                    xfm.as_ptr() as *const c_void,
                );
                sys::rtcCommitGeometry(geom);
                sys::rtcAttachGeometryByID(scene, geom, i as u32 + 1);
                sys::rtcReleaseGeometry(geom);
            }
            sys::rtcCommitScene(scene);
            match device.check("building the scene") {
                Ok(()) => Ok(s),
                Err(e) => Err(abandon(s, e)),
            }
        }
    }

    fn intersect_args(coherent: bool) -> sys::RTCIntersectArguments {
        sys::RTCIntersectArguments {
            flags: if coherent {
                sys::RTCRayQueryFlags::COHERENT
            } else {
                sys::RTCRayQueryFlags::INCOHERENT
            },
            feature_mask: sys::RTCFeatureFlags::RTC_FEATURE_FLAG_ALL,
            context: ptr::null_mut(),
            filter: None,
            intersect: None,
        }
    }

    fn occluded_args(coherent: bool) -> sys::RTCOccludedArguments {
        sys::RTCOccludedArguments {
            flags: if coherent {
                sys::RTCRayQueryFlags::COHERENT
            } else {
                sys::RTCRayQueryFlags::INCOHERENT
            },
            feature_mask: sys::RTCFeatureFlags::RTC_FEATURE_FLAG_ALL,
            context: ptr::null_mut(),
            filter: None,
            occluded: None,
        }
    }

    fn raw_ray(ray: &Ray) -> sys::RTCRay {
        sys::RTCRay {
            org_x: ray.org.x,
            org_y: ray.org.y,
            org_z: ray.org.z,
            tnear: ray.tnear,
            dir_x: ray.dir.x,
            dir_y: ray.dir.y,
            dir_z: ray.dir.z,
            time: 0.0,
            tfar: ray.tfar,
            mask: RAY_MASK,
            id: 0,
            flags: 0,
        }
    }

    /// Closest hit along `ray`, if any.
    pub fn intersect1(&self, ray: &Ray) -> Option<Hit> {
        let mut rh = RayHit1 {
            rh: sys::RTCRayHit {
                ray: Self::raw_ray(ray),
                hit: sys::RTCHit {
                    Ng_x: 0.0,
                    Ng_y: 0.0,
                    Ng_z: 0.0,
                    u: 0.0,
                    v: 0.0,
                    primID: INVALID_ID,
                    geomID: INVALID_ID,
                    instID: [INVALID_ID],
                },
            },
            _pad: [INVALID_ID; 4],
        };
        let mut args = Self::intersect_args(false);
        // SAFETY: committed scene; `rh` is 16-byte aligned with room for the 4.4 hit layout.
        unsafe { sys::rtcIntersect1(self.raw, &mut rh.rh, &mut args) };
        let h = &rh.rh.hit;
        (h.geomID != INVALID_ID).then(|| Hit {
            t: rh.rh.ray.tfar,
            inst: instance(h.instID[0]),
            prim_id: h.primID,
            u: h.u,
            v: h.v,
            ng: Vec3::new(h.Ng_x, h.Ng_y, h.Ng_z),
        })
    }

    /// Whether anything blocks `ray` within `[tnear, tfar]`.
    pub fn occluded1(&self, ray: &Ray) -> bool {
        let mut r = Self::raw_ray(ray);
        let mut args = Self::occluded_args(false);
        // SAFETY: committed scene; RTCRay is 16-byte aligned by its own repr.
        unsafe { sys::rtcOccluded1(self.raw, &mut r, &mut args) };
        // Embree marks an occluded ray by setting tfar to -inf.
        r.tfar == f32::NEG_INFINITY
    }

    /// Closest hits of the active lanes of a coherent packet.
    pub fn intersect16(&self, p: &mut Packet16) {
        self.intersect16_with(p, true)
    }

    /// Closest hits of the active lanes of a packet whose rays may be incoherent (Embree's
    /// `INCOHERENT` query flag).
    pub fn intersect16_incoherent(&self, p: &mut Packet16) {
        self.intersect16_with(p, false)
    }

    fn intersect16_with(&self, p: &mut Packet16, coherent: bool) {
        let mut args = Self::intersect_args(coherent);
        // SAFETY: the packet is 64-byte aligned with room for the 4.4 hit layout; geomID was
        // reset in `set` for every active lane.
        unsafe { sys::rtcIntersect16(p.active.as_ptr(), self.raw, &mut p.raw.rh, &mut args) };
    }

    /// Occlusion of the active lanes of a coherent packet; read with `Packet16::occluded`.
    pub fn occluded16(&self, p: &mut Packet16) {
        self.occluded16_with(p, true)
    }

    /// Occlusion of the active lanes of a packet whose rays may be incoherent.
    pub fn occluded16_incoherent(&self, p: &mut Packet16) {
        self.occluded16_with(p, false)
    }

    fn occluded16_with(&self, p: &mut Packet16, coherent: bool) {
        let mut args = Self::occluded_args(coherent);
        // SAFETY: as in `intersect16`; occluded16 writes only the ray part (tfar).
        unsafe { sys::rtcOccluded16(p.active.as_ptr(), self.raw, &mut p.raw.rh.ray, &mut args) };
        for lane in 0..16 {
            p.occluded[lane] = p.active[lane] != 0 && p.raw.rh.ray.tfar[lane] == f32::NEG_INFINITY;
        }
    }
}

/// The error of a scene whose build failed (out of memory, mostly), with the scene left
/// unreleased: a build that failed inside Embree's task system (TBB) leaves a task group that
/// was never waited for, and releasing the scene then ends the process in `std::terminate`
/// (seen under `ulimit -v`). What it holds is given up to the process's end, which follows
/// such an error.
fn abandon(s: TriangleScene, e: anyhow::Error) -> anyhow::Error {
    std::mem::forget(s);
    e
}

impl Drop for TriangleScene {
    fn drop(&mut self) {
        // SAFETY: handles valid, each released once (the device reference was retained in
        // `build`); the scene goes first, then the prototypes its instances referenced.
        unsafe {
            sys::rtcReleaseScene(self.raw);
            for p in &self.prototypes {
                sys::rtcReleaseScene(*p);
            }
            sys::rtcReleaseDevice(self.device);
        }
    }
}

/// Set flush-to-zero and denormals-are-zero on the calling thread, as Embree asks of every thread
/// that traces rays (its docs; with a non-TBB pool each worker must do it itself). Call it from
/// rayon's `start_handler` and on the main thread.
pub fn set_flush_denormals() {
    #[cfg(target_arch = "x86_64")]
    {
        let csr = mxcsr() | MXCSR_FTZ | MXCSR_DAZ;
        // SAFETY: loads MXCSR with only the FTZ/DAZ bits changed; SSE is part of x86_64.
        unsafe { std::arch::asm!("ldmxcsr [{}]", in(reg) &csr, options(nostack, readonly)) };
    }
}

#[cfg(target_arch = "x86_64")]
const MXCSR_FTZ: u32 = 1 << 15;
#[cfg(target_arch = "x86_64")]
const MXCSR_DAZ: u32 = 1 << 6;

#[cfg(target_arch = "x86_64")]
fn mxcsr() -> u32 {
    let mut csr = 0u32;
    // SAFETY: stores MXCSR into a local; no other effect.
    unsafe { std::arch::asm!("stmxcsr [{}]", in(reg) &mut csr, options(nostack)) };
    csr
}

/// Whether FTZ and DAZ are set on the calling thread (for tests).
pub fn flush_denormals_enabled() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        mxcsr() & (MXCSR_FTZ | MXCSR_DAZ) == MXCSR_FTZ | MXCSR_DAZ
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Sampler;

    /// Möller–Trumbore, as the brute-force oracle.
    fn brute(verts: &[Vec3], tris: &[[u32; 3]], ray: &Ray) -> Option<(u32, f32)> {
        let mut best: Option<(u32, f32)> = None;
        for (i, t) in tris.iter().enumerate() {
            let (a, b, c) = (
                verts[t[0] as usize],
                verts[t[1] as usize],
                verts[t[2] as usize],
            );
            let e1 = b - a;
            let e2 = c - a;
            let p = ray.dir.cross(e2);
            let det = e1.dot(p);
            if det.abs() < 1e-12 {
                continue;
            }
            let inv = 1.0 / det;
            let s = ray.org - a;
            let u = s.dot(p) * inv;
            if !(0.0..=1.0).contains(&u) {
                continue;
            }
            let q = s.cross(e1);
            let v = ray.dir.dot(q) * inv;
            if v < 0.0 || u + v > 1.0 {
                continue;
            }
            let tt = e2.dot(q) * inv;
            if tt > ray.tnear && tt < ray.tfar && best.is_none_or(|(_, bt)| tt < bt) {
                best = Some((i as u32, tt));
            }
        }
        best
    }

    fn random_scene(n: usize) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let mut s = Sampler::new(7, 0, 0, 0);
        let mut verts = Vec::new();
        let mut tris = Vec::new();
        for i in 0..n {
            let c = Vec3::new(s.next_1d(), s.next_1d(), s.next_1d()) * 4.0 - 2.0;
            for _ in 0..3 {
                verts.push(c + (Vec3::new(s.next_1d(), s.next_1d(), s.next_1d()) - 0.5) * 0.8);
            }
            tris.push([3 * i as u32, 3 * i as u32 + 1, 3 * i as u32 + 2]);
        }
        (verts, tris)
    }

    fn random_ray(s: &mut Sampler) -> Ray {
        let o = Vec3::new(s.next_1d(), s.next_1d(), s.next_1d()) * 6.0 - 3.0;
        let target = Vec3::new(s.next_1d(), s.next_1d(), s.next_1d()) * 3.0 - 1.5;
        Ray::new(o, (target - o).normalize())
    }

    #[test]
    fn version_is_embree4() {
        let d = Device::new().unwrap();
        assert!(d.version() >= 40000, "version {}", d.version());
    }

    #[test]
    fn intersect1_and_occluded1_match_brute_force() {
        let d = Device::new().unwrap();
        let (verts, tris) = random_scene(300);
        let scene = TriangleScene::new(&d, &verts, &tris).unwrap();
        let mut s = Sampler::new(11, 0, 0, 0);
        let (mut agree, mut hits, n) = (0, 0, 4000);
        for _ in 0..n {
            let ray = random_ray(&mut s);
            let e = scene.intersect1(&ray);
            let b = brute(&verts, &tris, &ray);
            assert_eq!(scene.occluded1(&ray), e.is_some());
            match (e, b) {
                (Some(h), Some((p, t))) => {
                    hits += 1;
                    if h.prim_id == p {
                        assert!((h.t - t).abs() < 1e-4 * (1.0 + t), "t {} vs {}", h.t, t);
                        agree += 1;
                    }
                }
                (None, None) => agree += 1,
                _ => {}
            }
        }
        // Rays grazing a shared edge may legitimately differ; anything more is a wrapper bug.
        assert!(agree >= n - 4, "{agree} of {n} agree");
        assert!(hits > n / 4, "too few hits ({hits}) to test anything");
    }

    #[test]
    fn packets_match_single_rays() {
        let d = Device::new().unwrap();
        let (verts, tris) = random_scene(300);
        let scene = TriangleScene::new(&d, &verts, &tris).unwrap();
        let mut s = Sampler::new(12, 0, 0, 0);
        let mut p = Packet16::new();
        for round in 0..200 {
            p.clear();
            let rays: Vec<Ray> = (0..16).map(|_| random_ray(&mut s)).collect();
            // Leave a lane inactive now and then: it must report nothing.
            let skip = round % 17;
            for (i, r) in rays.iter().enumerate() {
                if i != skip {
                    p.set(i, r);
                }
            }
            scene.intersect16(&mut p);
            for (i, r) in rays.iter().enumerate() {
                let single = scene.intersect1(r);
                if i == skip {
                    assert!(p.hit(i).is_none());
                    continue;
                }
                assert_eq!(p.hit(i).map(|h| h.prim_id), single.map(|h| h.prim_id));
            }
            p.clear();
            for (i, r) in rays.iter().enumerate() {
                if i != skip {
                    p.set(i, r);
                }
            }
            scene.occluded16(&mut p);
            for (i, r) in rays.iter().enumerate() {
                let expect = i != skip && scene.occluded1(r);
                assert_eq!(p.occluded(i), expect);
            }
        }
    }

    #[test]
    fn spawned_rays_do_not_hit_their_own_triangle() {
        let d = Device::new().unwrap();
        let verts = [
            Vec3::new(-1.0, 0.0, -1.0),
            Vec3::new(1.0, 0.0, -1.0),
            Vec3::new(0.0, 0.0, 1.0),
        ];
        let scene = TriangleScene::new(&d, &verts, &[[0, 1, 2]]).unwrap();
        let mut s = Sampler::new(3, 0, 0, 0);
        for _ in 0..1000 {
            let p = Vec3::new(s.next_1d() * 0.5 - 0.25, 0.0, s.next_1d() * 0.5 - 0.25);
            let dir =
                Vec3::new(s.next_1d() - 0.5, 0.05 + s.next_1d(), s.next_1d() - 0.5).normalize();
            assert!(scene
                .intersect1(&Ray::spawn(p, Vec3::Y, dir, 1.0))
                .is_none());
            assert!(scene
                .intersect1(&Ray::spawn(p, Vec3::Y, -dir, 1.0))
                .is_none());
        }
    }

    /// `between`'s segments (direction not unit) are occluded exactly when a triangle crosses
    /// the segment between their ends, against the brute-force test on the same segment as a
    /// unit ray; `from_eye` is `between` from a point off any surface, bit for bit.
    #[test]
    fn segments_between_points_match_brute_force() {
        let d = Device::new().unwrap();
        let (verts, tris) = random_scene(300);
        let scene = TriangleScene::new(&d, &verts, &tris).unwrap();
        let mut s = Sampler::new(13, 0, 0, 0);
        let point = |s: &mut Sampler, r: f32| {
            Vec3::new(s.next_1d(), s.next_1d(), s.next_1d()) * 2.0 * r - r
        };
        let (mut agree, mut blocked, n) = (0, 0, 4000);
        for _ in 0..n {
            let (p0, p1) = (point(&mut s, 3.0), point(&mut s, 3.0));
            let n1 = point(&mut s, 1.0).normalize_or_zero();
            let seg = Ray::between(p0, Vec3::ZERO, p1, n1, 1.0);
            let eye = Ray::from_eye(p0, p1, n1, 1.0);
            assert_eq!(
                (seg.org, seg.dir, seg.tnear, seg.tfar),
                (eye.org, eye.dir, eye.tnear, eye.tfar)
            );
            // The same segment as a unit ray whose tfar is its length.
            let len = seg.dir.length();
            let unit = Ray {
                org: seg.org,
                dir: seg.dir / len,
                tnear: 0.0,
                tfar: len * seg.tfar,
            };
            let occluded = scene.occluded1(&seg);
            blocked += occluded as usize;
            agree += (occluded == brute(&verts, &tris, &unit).is_some()) as usize;
        }
        // Segments ending on a shared edge may legitimately differ.
        assert!(agree >= n - 4, "{agree} of {n} agree");
        assert!(
            blocked > n / 4 && blocked < n - n / 4,
            "{blocked} of {n} blocked"
        );
    }

    #[test]
    fn bad_geometry_is_an_error() {
        let d = Device::new().unwrap();
        assert!(TriangleScene::new(&d, &[Vec3::ZERO], &[[0, 1, 2]]).is_err());
        assert!(TriangleScene::new(&d, &[Vec3::ZERO], &[]).is_err());
    }

    #[test]
    fn flush_denormals_sets_the_bits() {
        std::thread::spawn(|| {
            set_flush_denormals();
            assert!(flush_denormals_enabled());
        })
        .join()
        .unwrap();
    }
}
