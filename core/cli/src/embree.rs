//! Embree 4, loaded at run time from a shared library the user names
//! (`meso bench rays MESH --embree LIB`), so the tracer and Embree are timed in one
//! process on the same rays, alternating, and their ratio does not carry the drift
//! between two programs run one after the other. Only what a closest-hit comparison
//! needs: one triangle geometry, one committed scene, `rtcIntersect1` per ray.
//!
//! Embree ships no Rust binding here and is not a build dependency: the few C
//! declarations below follow Embree 4's public API (rtcore_device.h, rtcore_scene.h,
//! rtcore_geometry.h, rtcore_ray.h). The library's version is checked before any
//! call whose signature differs between Embree 3 and 4.

use std::ffi::{CString, c_char, c_int, c_uint, c_void};
use std::path::Path;
use std::time::Instant;

use anyhow::{Context, anyhow, bail};
use libloading::Library;

const GEOMETRY_TYPE_TRIANGLE: c_int = 0;
const BUFFER_TYPE_INDEX: c_int = 0;
const BUFFER_TYPE_VERTEX: c_int = 1;
const FORMAT_UINT3: c_int = 0x5003;
const FORMAT_FLOAT3: c_int = 0x9003;
const BUILD_QUALITY_MEDIUM: c_int = 1;
const DEVICE_PROPERTY_VERSION: c_int = 0;
const INVALID_GEOMETRY_ID: c_uint = c_uint::MAX;

/// `RTCRay`.
#[repr(C, align(16))]
struct Ray {
    org: [f32; 3],
    tnear: f32,
    dir: [f32; 3],
    time: f32,
    tfar: f32,
    mask: c_uint,
    id: c_uint,
    flags: c_uint,
}

/// `RTCHit`: Ng, u, v, primID, geomID, then the instance IDs, padded so that a
/// library built with more instance levels or with instance arrays still fits.
#[repr(C, align(16))]
struct Hit {
    ng: [f32; 3],
    u: f32,
    v: f32,
    prim_id: c_uint,
    geom_id: c_uint,
    inst: [c_uint; 5],
}

/// `RTCRayHit`.
#[repr(C)]
struct RayHit {
    ray: Ray,
    hit: Hit,
}

type Handle = *mut c_void;

/// The entry points used, resolved once.
struct Api {
    new_device: unsafe extern "C" fn(*const c_char) -> Handle,
    get_device_error: unsafe extern "C" fn(Handle) -> c_int,
    get_device_property: unsafe extern "C" fn(Handle, c_int) -> isize,
    release_device: unsafe extern "C" fn(Handle),
    new_scene: unsafe extern "C" fn(Handle) -> Handle,
    set_scene_build_quality: unsafe extern "C" fn(Handle, c_int),
    commit_scene: unsafe extern "C" fn(Handle),
    release_scene: unsafe extern "C" fn(Handle),
    new_geometry: unsafe extern "C" fn(Handle, c_int) -> Handle,
    set_new_geometry_buffer:
        unsafe extern "C" fn(Handle, c_int, c_uint, c_int, usize, usize) -> *mut c_void,
    commit_geometry: unsafe extern "C" fn(Handle),
    attach_geometry: unsafe extern "C" fn(Handle, Handle) -> c_uint,
    release_geometry: unsafe extern "C" fn(Handle),
    intersect1: unsafe extern "C" fn(Handle, *mut RayHit, *mut c_void),
}

/// A committed Embree scene of one triangle geometry.
pub struct Embree {
    api: Api,
    device: Handle,
    scene: Handle,
    /// "major.minor.patch" as the library reports it.
    pub version: String,
    /// Milliseconds `rtcCommitScene` took (Embree's BVH build, medium quality).
    pub build_ms: f64,
}

// SAFETY: Embree's API allows `rtcIntersect1` on a committed scene from any number of
// threads at once; nothing else is called after `load` until `drop`, which takes
// `&mut self`.
unsafe impl Sync for Embree {}

impl Embree {
    /// Loads the library at `path` and builds a scene of `triangles` (three f32
    /// vertices each) with Embree's default quality for a static scene.
    pub fn load(path: &Path, triangles: &[[[f32; 3]; 3]]) -> anyhow::Result<Self> {
        // SAFETY: loading a library runs its initialisers; the user named it as Embree.
        let library = unsafe { Library::new(path) }
            .with_context(|| format!("cannot load `{}`", path.display()))?;
        let api = Api::resolve(&library)
            .with_context(|| format!("`{}` is not an Embree library", path.display()))?;
        // Never unloaded: Embree's task threads (TBB) outlive its scenes, and unloading
        // the code under them crashes the process at exit. The entry points above stay
        // valid for the rest of the process.
        std::mem::forget(library);
        let n = triangles.len();
        if 3 * n > c_uint::MAX as usize {
            bail!("{n} triangles: more than an Embree index buffer addresses");
        }
        let config = CString::new("threads=1").expect("no NUL");
        // SAFETY: the calls follow Embree's API; every handle is checked before use.
        unsafe {
            let device = (api.new_device)(config.as_ptr());
            if device.is_null() {
                bail!(
                    "`{}`: rtcNewDevice failed (error {})",
                    path.display(),
                    (api.get_device_error)(std::ptr::null_mut())
                );
            }
            let version = (api.get_device_property)(device, DEVICE_PROPERTY_VERSION);
            if !(40000..50000).contains(&version) {
                (api.release_device)(device);
                bail!(
                    "`{}` is Embree {}.{}.{}; the comparison needs Embree 4",
                    path.display(),
                    version / 10000,
                    version / 100 % 100,
                    version % 100
                );
            }
            let scene = (api.new_scene)(device);
            let geometry = (api.new_geometry)(device, GEOMETRY_TYPE_TRIANGLE);
            let vertices = (api.set_new_geometry_buffer)(
                geometry,
                BUFFER_TYPE_VERTEX,
                0,
                FORMAT_FLOAT3,
                3 * size_of::<f32>(),
                3 * n,
            )
            .cast::<[f32; 3]>();
            let indices = (api.set_new_geometry_buffer)(
                geometry,
                BUFFER_TYPE_INDEX,
                0,
                FORMAT_UINT3,
                3 * size_of::<c_uint>(),
                n,
            )
            .cast::<[c_uint; 3]>();
            if scene.is_null() || geometry.is_null() || vertices.is_null() || indices.is_null() {
                let error = (api.get_device_error)(device);
                (api.release_device)(device);
                bail!(
                    "`{}`: Embree could not make the scene (error {error})",
                    path.display()
                );
            }
            for (i, t) in triangles.iter().enumerate() {
                // Below c_uint::MAX: checked above.
                let first = (3 * i) as c_uint;
                *indices.add(i) = [first, first + 1, first + 2];
                for (k, v) in t.iter().enumerate() {
                    *vertices.add(3 * i + k) = *v;
                }
            }
            (api.commit_geometry)(geometry);
            (api.attach_geometry)(scene, geometry);
            (api.release_geometry)(geometry);
            (api.set_scene_build_quality)(scene, BUILD_QUALITY_MEDIUM);
            let start = Instant::now();
            (api.commit_scene)(scene);
            let build_ms = start.elapsed().as_secs_f64() * 1e3;
            let error = (api.get_device_error)(device);
            if error != 0 {
                (api.release_scene)(scene);
                (api.release_device)(device);
                bail!(
                    "`{}`: Embree error {error} building the scene",
                    path.display()
                );
            }
            Ok(Self {
                api,
                device,
                scene,
                version: format!(
                    "{}.{}.{}",
                    version / 10000,
                    version / 100 % 100,
                    version % 100
                ),
                build_ms,
            })
        }
    }

    /// The closest hit's distance along the ray from `origin` in unit direction `dir`
    /// within [0, infinity), as `rtcIntersect1` finds it.
    pub fn closest(&self, origin: [f32; 3], dir: [f32; 3]) -> Option<f32> {
        let mut rh = RayHit {
            ray: Ray {
                org: origin,
                tnear: 0.0,
                dir,
                time: 0.0,
                tfar: f32::INFINITY,
                mask: c_uint::MAX,
                id: 0,
                flags: 0,
            },
            hit: Hit {
                ng: [0.0; 3],
                u: 0.0,
                v: 0.0,
                prim_id: INVALID_GEOMETRY_ID,
                geom_id: INVALID_GEOMETRY_ID,
                inst: [INVALID_GEOMETRY_ID; 5],
            },
        };
        // SAFETY: a committed scene, a properly aligned ray-hit record, no arguments.
        unsafe { (self.api.intersect1)(self.scene, &mut rh, std::ptr::null_mut()) };
        (rh.hit.geom_id != INVALID_GEOMETRY_ID).then_some(rh.ray.tfar)
    }
}

impl Drop for Embree {
    fn drop(&mut self) {
        // SAFETY: both handles came from this library and are released once.
        unsafe {
            (self.api.release_scene)(self.scene);
            (self.api.release_device)(self.device);
        }
    }
}

impl Api {
    fn resolve(library: &Library) -> anyhow::Result<Self> {
        /// One entry point by name, typed as the declaration above says.
        fn get<T: Copy>(library: &Library, name: &str) -> anyhow::Result<T> {
            // SAFETY: the type given for each name is Embree 4's declaration of it.
            unsafe { library.get::<T>(name.as_bytes()) }
                .map(|symbol| *symbol)
                .map_err(|e| anyhow!("no `{name}`: {e}"))
        }
        Ok(Self {
            new_device: get(library, "rtcNewDevice")?,
            get_device_error: get(library, "rtcGetDeviceError")?,
            get_device_property: get(library, "rtcGetDeviceProperty")?,
            release_device: get(library, "rtcReleaseDevice")?,
            new_scene: get(library, "rtcNewScene")?,
            set_scene_build_quality: get(library, "rtcSetSceneBuildQuality")?,
            commit_scene: get(library, "rtcCommitScene")?,
            release_scene: get(library, "rtcReleaseScene")?,
            new_geometry: get(library, "rtcNewGeometry")?,
            set_new_geometry_buffer: get(library, "rtcSetNewGeometryBuffer")?,
            commit_geometry: get(library, "rtcCommitGeometry")?,
            attach_geometry: get(library, "rtcAttachGeometry")?,
            release_geometry: get(library, "rtcReleaseGeometry")?,
            intersect1: get(library, "rtcIntersect1")?,
        })
    }
}
