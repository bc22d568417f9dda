//! The raymesh ray tracer: scenes described in JSON (see
//! `docs/scene-format.md`), built into a two-level acceleration structure
//! (one bottom structure per mesh, instances on top), and rendered
//! Whitted-style (Whitted, "An improved illumination model for shaded
//! display", 1980) on all cores, or as a heat map of what each ray cost.

mod camera;
mod demo;
mod desc;
mod image_out;
mod render;
mod world;

pub use camera::{Camera, CameraError, UP_ALONG_VIEW};
pub use demo::{demo_scene, torus_knot};
pub use desc::{
    AmbientDesc, CameraDesc, DirectionalDesc, ImageDesc, LightDesc, MaterialDesc, MeshDesc,
    PointDesc, Rgb, SceneDesc, SceneError, Shading, SphereDesc, SurfaceDesc, TransformDesc,
    TriangleDesc,
};
pub use image_out::{heat_color, save_png, to_srgb8};
pub use render::{render, Mode, Options, Rendered};
pub use world::{Light, Material, World, WorldBytes};
