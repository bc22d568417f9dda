//! The JSON scene format (documented in `docs/scene-format.md`), read with
//! serde. Unknown keys and wrong types are errors that name the file, the
//! line and column, and the JSON path of the offending value.

use serde::de::IgnoredAny;
use serde::Deserialize;
use serde_json::value::RawValue;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A scene file, as written.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneDesc {
    /// The camera.
    pub camera: CameraDesc,
    /// Image size, samples and background.
    #[serde(default)]
    pub image: ImageDesc,
    /// Light sources.
    #[serde(default)]
    pub lights: Vec<LightDesc>,
    /// Named materials; surfaces refer to them by name.
    #[serde(default)]
    pub materials: BTreeMap<String, MaterialDesc>,
    /// What is in the scene.
    #[serde(default)]
    pub surfaces: Vec<SurfaceDesc>,
    /// Acceleration structure (any name `raymesh raycast --accel` takes).
    #[serde(default = "default_accel")]
    pub accel: String,
    /// Spatial splits for the meshes' binned-SAH BVHs: extra references
    /// as a fraction of triangles, 0 (the default) for none (see
    /// `raymesh_accel::BuildConfig::spatial_splits`).
    #[serde(default)]
    pub spatial_splits: f32,
    /// Reinsertion optimization of the meshes' BVHs after their build
    /// (see `raymesh_accel::BuildConfig::optimize`); off by default.
    #[serde(default)]
    pub optimize: bool,
    /// Most mirror bounces.
    #[serde(default = "default_depth")]
    pub max_depth: u32,
}

fn default_accel() -> String {
    "bvh".into()
}
fn default_depth() -> u32 {
    5
}
fn white() -> [f32; 3] {
    [1.0; 3]
}
fn one() -> f32 {
    1.0
}

/// Camera: eye, target, up and vertical field of view in degrees.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraDesc {
    /// Eye position.
    pub eye: [f32; 3],
    /// Point looked at.
    pub target: [f32; 3],
    /// Up direction (default +Y).
    #[serde(default = "up")]
    pub up: [f32; 3],
    /// Vertical field of view, degrees (default 40).
    #[serde(default = "fov")]
    pub fov: f32,
}

fn up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}
fn fov() -> f32 {
    40.0
}

/// Image settings.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImageDesc {
    /// Width in pixels (default 800).
    #[serde(default = "width")]
    pub width: u32,
    /// Height in pixels (default 600).
    #[serde(default = "height")]
    pub height: u32,
    /// Samples per pixel, stratified (default 4).
    #[serde(default = "spp")]
    pub spp: u32,
    /// Colour of rays that hit nothing, linear RGB (default a dark blue).
    #[serde(default = "background")]
    pub background: [f32; 3],
}

fn width() -> u32 {
    800
}
fn height() -> u32 {
    600
}
fn spp() -> u32 {
    4
}
fn background() -> [f32; 3] {
    [0.04, 0.05, 0.08]
}

impl Default for ImageDesc {
    fn default() -> Self {
        Self {
            width: width(),
            height: height(),
            spp: spp(),
            background: background(),
        }
    }
}

/// A light source; `color` is linear RGB, scaled by `intensity`.
#[derive(Clone, Debug, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum LightDesc {
    /// Light from everywhere, scaled by each material's `ambient`.
    Ambient(AmbientDesc),
    /// A point light; its irradiance falls off as `1 / distance²`.
    Point(PointDesc),
    /// A light at infinity shining along `direction`.
    Directional(DirectionalDesc),
}

/// An ambient light.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AmbientDesc {
    #[serde(rename = "type", default, skip_serializing)]
    _tag: IgnoredAny,
    /// Colour (default white).
    #[serde(default = "white")]
    pub color: [f32; 3],
    /// Scale (default 1).
    #[serde(default = "one")]
    pub intensity: f32,
}

/// A point light.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PointDesc {
    #[serde(rename = "type", default, skip_serializing)]
    _tag: IgnoredAny,
    /// Position.
    pub position: [f32; 3],
    /// Colour (default white).
    #[serde(default = "white")]
    pub color: [f32; 3],
    /// Scale (default 1).
    #[serde(default = "one")]
    pub intensity: f32,
}

/// A directional light.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DirectionalDesc {
    #[serde(rename = "type", default, skip_serializing)]
    _tag: IgnoredAny,
    /// Direction the light travels.
    pub direction: [f32; 3],
    /// Colour (default white).
    #[serde(default = "white")]
    pub color: [f32; 3],
    /// Scale (default 1).
    #[serde(default = "one")]
    pub intensity: f32,
}

/// A Blinn-Phong material with mirror reflectance.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialDesc {
    /// Reflectance of ambient light (default 0.1 grey).
    #[serde(default = "ambient")]
    pub ambient: [f32; 3],
    /// Lambertian reflectance (default 0.7 grey).
    #[serde(default = "diffuse")]
    pub diffuse: [f32; 3],
    /// Specular reflectance (default black).
    #[serde(default)]
    pub specular: [f32; 3],
    /// Blinn-Phong exponent (default 32).
    #[serde(default = "shininess")]
    pub shininess: f32,
    /// Mirror reflectance, a number or an RGB triple (default 0).
    #[serde(default)]
    pub mirror: Rgb,
}

fn ambient() -> [f32; 3] {
    [0.1; 3]
}
fn diffuse() -> [f32; 3] {
    [0.7; 3]
}
fn shininess() -> f32 {
    32.0
}

impl Default for MaterialDesc {
    fn default() -> Self {
        Self {
            ambient: ambient(),
            diffuse: diffuse(),
            specular: [0.0; 3],
            shininess: shininess(),
            mirror: Rgb::Grey(0.0),
        }
    }
}

/// A colour written as one number (grey) or three.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(untagged)]
pub enum Rgb {
    /// The same value in every channel.
    Grey(f32),
    /// Red, green, blue.
    Rgb([f32; 3]),
}

impl Default for Rgb {
    fn default() -> Self {
        Self::Grey(0.0)
    }
}

impl Rgb {
    /// As an RGB triple.
    #[must_use]
    pub fn rgb(self) -> [f32; 3] {
        match self {
            Self::Grey(g) => [g; 3],
            Self::Rgb(c) => c,
        }
    }
}

/// Something to render.
#[derive(Clone, Debug, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum SurfaceDesc {
    /// A sphere.
    Sphere(SphereDesc),
    /// One triangle (both sides shaded).
    Triangle(TriangleDesc),
    /// A mesh file, placed once or many times.
    Mesh(MeshDesc),
}

/// A sphere.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SphereDesc {
    #[serde(rename = "type", default, skip_serializing)]
    _tag: IgnoredAny,
    /// Centre.
    pub center: [f32; 3],
    /// Radius.
    pub radius: f32,
    /// Material name (default: a grey diffuse one).
    #[serde(default)]
    pub material: Option<String>,
}

/// One triangle.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TriangleDesc {
    #[serde(rename = "type", default, skip_serializing)]
    _tag: IgnoredAny,
    /// Corners.
    pub vertices: [[f32; 3]; 3],
    /// Material name.
    #[serde(default)]
    pub material: Option<String>,
}

/// A mesh file (OBJ, OFF, PLY, STL), relative to the scene file, or
/// `builtin:torus-knot`; placed once by `transform`, or once per entry of
/// `instances` (one copy of the mesh in memory either way).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshDesc {
    #[serde(rename = "type", default, skip_serializing)]
    _tag: IgnoredAny,
    /// Path of the mesh file.
    pub file: String,
    /// Material name.
    #[serde(default)]
    pub material: Option<String>,
    /// `smooth` (interpolated vertex normals, the default) or `flat`.
    #[serde(default)]
    pub shading: Shading,
    /// Placement (default identity).
    #[serde(default)]
    pub transform: TransformDesc,
    /// Several placements instead of `transform`.
    #[serde(default)]
    pub instances: Option<Vec<TransformDesc>>,
}

/// How a mesh is shaded.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Shading {
    /// Vertex normals interpolated across each triangle.
    #[default]
    Smooth,
    /// The triangle's own normal.
    Flat,
}

/// Scale, then rotate about x, then y, then z (degrees), then translate.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransformDesc {
    /// Translation.
    #[serde(default)]
    pub translate: [f32; 3],
    /// Rotation angles about x, y and z, degrees, applied in that order.
    #[serde(default)]
    pub rotate: [f32; 3],
    /// Uniform scale (a number) or per axis (three).
    #[serde(default = "unit_scale")]
    pub scale: Rgb,
}

fn unit_scale() -> Rgb {
    Rgb::Grey(1.0)
}

impl Default for TransformDesc {
    fn default() -> Self {
        Self {
            translate: [0.0; 3],
            rotate: [0.0; 3],
            scale: unit_scale(),
        }
    }
}

/// An error in a scene: the file, where in it, and what is wrong.
#[derive(Debug, thiserror::Error)]
#[error("{}{}{}: {message}", file.display(), line.map(|(l, c)| format!(":{l}:{c}")).unwrap_or_default(), if json_path.is_empty() || json_path == "." { String::new() } else { format!(": at {json_path}") })]
pub struct SceneError {
    /// The scene file (or `<demo>`).
    pub file: PathBuf,
    /// Line and column, when the JSON parser knows them.
    pub line: Option<(usize, usize)>,
    /// Path of the offending value, such as `surfaces[2].radius`.
    pub json_path: String,
    /// What is wrong.
    pub message: String,
}

impl SceneError {
    /// An error at a JSON path, without a line.
    #[must_use]
    pub fn at(file: &Path, json_path: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            file: file.to_path_buf(),
            line: None,
            json_path: json_path.into(),
            message: message.into(),
        }
    }
}

impl SceneDesc {
    /// Parses scene JSON; `file` names it in errors.
    pub fn parse(text: &str, file: &Path) -> Result<Self, SceneError> {
        // A byte-order mark, as some Windows editors write, is no JSON
        // value: serde_json stops at it (positions after it are the ones
        // an editor shows, which hides the mark).
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        located::<Self>(text, file).map_err(|e| refine(text, file, e))
    }

    /// Reads and parses a scene file.
    pub fn load(file: &Path) -> Result<Self, SceneError> {
        let text = std::fs::read_to_string(file)
            .map_err(|e| SceneError::at(file, "", format!("cannot read: {e}")))?;
        Self::parse(&text, file)
    }
}

/// Deserializes with the JSON path and position of any error.
fn located<T: serde::de::DeserializeOwned>(text: &str, file: &Path) -> Result<T, SceneError> {
    let de = &mut serde_json::Deserializer::from_str(text);
    serde_path_to_error::deserialize(de).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner();
        let message = inner.to_string();
        // serde_json appends " at line L column C"; keep the message alone.
        let message = match message.rfind(" at line ") {
            Some(i) => message[..i].to_string(),
            None => message,
        };
        SceneError {
            file: file.to_path_buf(),
            line: (inner.line() > 0).then(|| (inner.line(), inner.column())),
            json_path: path,
            message,
        }
    })
}

/// serde reads a `"type"`-tagged element as a whole, so an error inside it
/// stops at `surfaces[i]`, placed at the element's end. Re-read that one
/// element as its variant's struct to name the field and its position.
fn refine(text: &str, file: &Path, e: SceneError) -> SceneError {
    #[derive(Deserialize)]
    struct Lists<'a> {
        #[serde(borrow, default)]
        surfaces: Vec<&'a RawValue>,
        #[serde(borrow, default)]
        lights: Vec<&'a RawValue>,
    }
    #[derive(Deserialize)]
    struct Tag {
        #[serde(rename = "type")]
        kind: String,
    }
    let Some((list, index)) = e
        .json_path
        .strip_suffix(']')
        .and_then(|p| p.split_once('['))
    else {
        return e;
    };
    let (Ok(index), Ok(lists)) = (index.parse::<usize>(), serde_json::from_str::<Lists>(text))
    else {
        return e;
    };
    let raw = match list {
        "surfaces" => lists.surfaces.get(index),
        "lights" => lists.lights.get(index),
        _ => None,
    };
    let Some(raw) = raw.map(|r| r.get()) else {
        return e;
    };
    let Ok(tag) = serde_json::from_str::<Tag>(raw) else {
        return e;
    };
    let inner = match (list, tag.kind.as_str()) {
        ("surfaces", "sphere") => located::<SphereDesc>(raw, file).err(),
        ("surfaces", "triangle") => located::<TriangleDesc>(raw, file).err(),
        ("surfaces", "mesh") => located::<MeshDesc>(raw, file).err(),
        ("lights", "ambient") => located::<AmbientDesc>(raw, file).err(),
        ("lights", "point") => located::<PointDesc>(raw, file).err(),
        ("lights", "directional") => located::<DirectionalDesc>(raw, file).err(),
        _ => None,
    };
    let Some(inner) = inner else { return e };
    // Where the element starts in the file, to offset the inner position.
    let start = raw.as_ptr() as usize - text.as_ptr() as usize;
    let before = &text[..start];
    let base_line = before.matches('\n').count() + 1;
    let base_col = start - before.rfind('\n').map_or(0, |i| i + 1) + 1;
    let line = inner.line.map(|(l, c)| {
        if l == 1 {
            (base_line, base_col + c - 1)
        } else {
            (base_line + l - 1, c)
        }
    });
    let sub = if inner.json_path == "." {
        String::new()
    } else {
        format!(".{}", inner.json_path)
    };
    SceneError {
        line: line.or(e.line),
        json_path: format!("{}{sub}", e.json_path),
        ..inner
    }
}
