//! A scene ready to render: the camera, lights, materials, and every
//! surface under one two-level acceleration structure.

use crate::desc::{AmbientDesc, DirectionalDesc, PointDesc};
use crate::desc::{
    LightDesc, MeshDesc, SceneDesc, Shading, SphereDesc, SurfaceDesc, TransformDesc, TriangleDesc,
};
use crate::{Camera, CameraError, SceneError};
use raymesh_accel::{
    AccelKind, BuildConfig, CountStats, Hit, Instance, Instances, Ray, Scene, Shape, Shapes,
    Surface, TriangleMesh, Triangles, LANES,
};
use raymesh_geometry::{decode_unit, encode_unit, Aabb, Mat4, Quat, Sphere, Vec3};
use raymesh_mesh::{normals::vertex_normals, IndexedMesh};
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};
use std::path::Path;
use std::time::Instant;

/// A Blinn-Phong material with mirror reflectance (linear RGB).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Reflectance of ambient light.
    pub ambient: Vec3,
    /// Lambertian reflectance.
    pub diffuse: Vec3,
    /// Specular reflectance.
    pub specular: Vec3,
    /// Blinn-Phong exponent.
    pub shininess: f32,
    /// Mirror reflectance.
    pub mirror: Vec3,
}

impl Default for Material {
    fn default() -> Self {
        Self {
            ambient: Vec3::splat(0.1),
            diffuse: Vec3::splat(0.7),
            specular: Vec3::ZERO,
            shininess: 32.0,
            mirror: Vec3::ZERO,
        }
    }
}

/// A light that casts shadows.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Light {
    /// Point light: position and intensity (colour × scale); falls off as 1/r².
    Point(Vec3, Vec3),
    /// Directional light: unit direction toward the light, and its radiance.
    Directional(Vec3, Vec3),
}

/// Bytes a [`World`] keeps, as [`World::bytes`] counts them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WorldBytes {
    /// Both levels of structure, with the copies of the primitives they
    /// test (a mesh's triangle corners, the loose shapes).
    pub structure: usize,
    /// What shading adds: meshes' encoded corner normals (12 bytes a
    /// triangle, for meshes shaded smooth) and the loose shapes' materials.
    pub shading: usize,
    /// Triangles of the meshes, each mesh once however often it is placed.
    pub triangles: usize,
}

/// A hit being shaded: its material, shading and geometric normals (both
/// turned toward the viewer), the direction back to the viewer, and the
/// point shadow rays leave from (lifted off the surface).
struct ShadePoint {
    mat: Material,
    n: Vec3,
    ng: Vec3,
    view: Vec3,
    p: Vec3,
}

/// A light seen from a [`ShadePoint`]: the shadow ray toward it, the unit
/// direction to it, the radiance it brings, and the cosine at the surface.
#[derive(Clone, Copy)]
struct LightRay {
    ray: Ray,
    l: Vec3,
    radiance: Vec3,
    cos: f32,
}

impl ShadePoint {
    /// The shadow ray toward `light`, unless the light is behind the
    /// surface (by the shading or the geometric normal).
    fn toward(&self, light: &Light) -> Option<LightRay> {
        let (l, dist, radiance) = match *light {
            Light::Point(pos, intensity) => {
                let to = pos - self.p;
                let d2 = to.length_squared();
                let d = d2.sqrt();
                (to / d, d, intensity / d2)
            }
            Light::Directional(to_light, radiance) => (to_light, f32::INFINITY, radiance),
        };
        let cos = self.n.dot(l);
        if cos <= 0.0 || self.ng.dot(l) <= 0.0 {
            return None;
        }
        Some(LightRay {
            ray: Ray::new(self.p, l, 0.0, dist * (1.0 - 1e-4)),
            l,
            radiance,
            cos,
        })
    }

    /// Adds what an unshadowed light brings to `color`: Lambert, then
    /// Blinn-Phong where the material is specular (two sums, in that
    /// order, as the image's bits depend on it).
    fn add_lit(&self, s: &LightRay, color: &mut Vec3) {
        *color += self.mat.diffuse * s.radiance * s.cos;
        if self.mat.specular != Vec3::ZERO {
            let h = (s.l + self.view).normalize_or_zero();
            *color +=
                self.mat.specular * s.radiance * self.n.dot(h).max(0.0).powf(self.mat.shininess);
        }
    }
}

/// One bottom-level object: a mesh, or the loose spheres and triangles.
enum Object {
    Mesh(Scene<Triangles>),
    Shapes(Scene<Shapes>),
}

impl Surface for Object {
    fn bounds(&self) -> Aabb {
        match self {
            Self::Mesh(s) => s.bounds(),
            Self::Shapes(s) => s.bounds(),
        }
    }
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        match self {
            Self::Mesh(s) => s.intersect(ray),
            Self::Shapes(s) => s.intersect(ray),
        }
    }
    fn occluded(&self, ray: &Ray) -> bool {
        match self {
            Self::Mesh(s) => s.occluded(ray),
            Self::Shapes(s) => s.occluded(ray),
        }
    }
    fn intersect8(&self, rays: &[Ray; LANES]) -> [Option<Hit>; LANES] {
        match self {
            Self::Mesh(s) => s.intersect8(rays),
            Self::Shapes(s) => s.intersect8(rays),
        }
    }
    fn occluded8(&self, rays: &[Ray; LANES]) -> [bool; LANES] {
        match self {
            Self::Mesh(s) => s.occluded8(rays),
            Self::Shapes(s) => s.occluded8(rays),
        }
    }
    fn intersect_stream(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
        match self {
            Self::Mesh(s) => s.intersect_stream(rays, out),
            Self::Shapes(s) => s.intersect_stream(rays, out),
        }
    }
    fn occluded_stream(&self, rays: &[Ray], out: &mut [bool]) {
        match self {
            Self::Mesh(s) => s.occluded_stream(rays, out),
            Self::Shapes(s) => s.occluded_stream(rays, out),
        }
    }
    fn intersect_count(&self, ray: &Ray, stats: &mut CountStats) -> Option<Hit> {
        match self {
            Self::Mesh(s) => s.intersect_counted(ray, stats),
            Self::Shapes(s) => s.intersect_counted(ray, stats),
        }
    }
}

/// What shading needs to know about a mesh object.
struct MeshData {
    /// Triangles in the mesh.
    triangles: usize,
    /// Per triangle (in the mesh's order), its corners' vertex normals,
    /// octahedral-encoded ([`encode_unit`]): 12 bytes a triangle, where
    /// the corner indices and a normal per vertex took 18. Empty when no
    /// surface shades the mesh smooth.
    corner_normals: Vec<[u32; 3]>,
}

/// Angle-weighted vertex normals, encoded ([`encode_unit`]): a third of
/// the memory of `Vec3`s while the structure is built beside them.
fn encoded_vertex_normals(mesh: &IndexedMesh) -> Vec<u32> {
    vertex_normals(mesh)
        .into_par_iter()
        .map(encode_unit)
        .collect()
}

/// Each triangle's corner normals, encoded, from encoded per-vertex
/// normals: written over the triangles' corner indices, so that no second
/// array of the same size is made.
fn corner_normals(mut triangles: Vec<[u32; 3]>, normals: &[u32]) -> Vec<[u32; 3]> {
    triangles
        .par_iter_mut()
        .for_each(|t| *t = t.map(|v| normals[v as usize]));
    triangles
}

/// Per instance: its material and shading.
#[derive(Clone, Copy)]
struct InstanceInfo {
    material: u32,
    smooth: bool,
}

/// A scene ready to render.
pub struct World {
    /// The camera.
    pub camera: Camera,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Colour of rays that hit nothing.
    pub background: Vec3,
    /// Most mirror bounces.
    pub max_depth: u32,
    /// Ambient light.
    pub ambient: Vec3,
    /// Lights that cast shadows.
    pub lights: Vec<Light>,
    materials: Vec<Material>,
    scene: Instances<Object>,
    meshes: Vec<MeshData>,
    instances: Vec<InstanceInfo>,
    /// Material of each loose shape (the shapes object's primitives).
    shape_materials: Vec<u32>,
    /// Triangles drawn, counting every instance.
    pub triangles: usize,
    /// The structure used (both levels).
    pub accel: AccelKind,
    /// Milliseconds spent building the structures.
    pub build_ms: f64,
    /// Offset for secondary rays, a small fraction of the scene's size.
    epsilon: f32,
}

/// A scene value for an error message: an infinite one is what a number
/// past `f32`'s range (about 3.4e38) in the file reads as.
fn shown(x: f32) -> String {
    if x.is_infinite() {
        format!("{x} (or a number past f32's range, about 3.4e38)")
    } else {
        x.to_string()
    }
}

fn v3(a: [f32; 3]) -> Vec3 {
    Vec3::from_array(a)
}

fn transform(t: &TransformDesc) -> Mat4 {
    let [rx, ry, rz] = t.rotate.map(f32::to_radians);
    let rot = Quat::from_rotation_z(rz) * Quat::from_rotation_y(ry) * Quat::from_rotation_x(rx);
    Mat4::from_scale_rotation_translation(v3(t.scale.rgb()), rot, v3(t.translate))
}

impl World {
    /// Builds a scene from its description. `file` names the scene in
    /// errors; `load_mesh` turns a surface's `file` into a mesh.
    pub fn build(
        desc: &SceneDesc,
        file: &Path,
        load_mesh: &dyn Fn(&str) -> Result<IndexedMesh, String>,
    ) -> Result<Self, SceneError> {
        let err = |path: String, msg: String| SceneError::at(file, path, msg);
        let accel: AccelKind = desc.accel.parse().map_err(|e| err("accel".into(), e))?;
        if !(0.0..=4.0).contains(&desc.spatial_splits) {
            return Err(err(
                "spatial_splits".into(),
                format!("{} is not a fraction in 0..=4", desc.spatial_splits),
            ));
        }
        let config = BuildConfig {
            spatial_splits: desc.spatial_splits,
            optimize: desc.optimize,
            ..BuildConfig::default()
        };
        let img = &desc.image;
        // At most 2^27 pixels (16 bytes each while rendering: about 2 GiB).
        let pixels = img.width as u64 * img.height as u64;
        if img.width == 0
            || img.height == 0
            || img.width > 1 << 15
            || img.height > 1 << 15
            || pixels > 1 << 27
        {
            return Err(err(
                "image".into(),
                format!(
                    "image size {}×{} must be within 1..=32768 per side and 134,217,728 pixels",
                    img.width, img.height
                ),
            ));
        }
        if img.spp == 0 || img.spp > 4096 {
            return Err(err(
                "image.spp".into(),
                "samples per pixel must be within 1..=4096".into(),
            ));
        }
        // Colours, intensities and exponents: finite and not negative (a
        // negative intensity subtracted light and drew a lit sphere black,
        // an infinite one drew it white, a light placed past `f32`'s range
        // left it black: none is what a scene means). A value past `f32`'s
        // range reads as infinite.
        let amount = |path: String, x: f32| -> Result<(), SceneError> {
            if x.is_finite() && x >= 0.0 {
                Ok(())
            } else {
                Err(err(
                    path,
                    format!("expected a finite value of at least 0, got {}", shown(x)),
                ))
            }
        };
        let color = |path: String, c: [f32; 3]| -> Result<(), SceneError> {
            for (k, &x) in c.iter().enumerate() {
                amount(format!("{path}[{k}]"), x)?;
            }
            Ok(())
        };
        let point = |path: String, p: [f32; 3]| -> Result<(), SceneError> {
            match p.iter().position(|x| !x.is_finite()) {
                None => Ok(()),
                Some(k) => Err(err(
                    format!("{path}[{k}]"),
                    format!("expected a finite coordinate, got {}", shown(p[k])),
                )),
            }
        };
        color("image.background".into(), img.background)?;
        let c = &desc.camera;
        point("camera.eye".into(), c.eye)?;
        point("camera.target".into(), c.target)?;
        point("camera.up".into(), c.up)?;
        let camera = Camera::try_look_at(
            v3(c.eye),
            v3(c.target),
            v3(c.up),
            c.fov,
            img.width as f32 / img.height as f32,
        )
        .map_err(|e| {
            let at = match e {
                CameraError::NoUp => "camera.up",
                CameraError::Fov(_) => "camera.fov",
                _ => "camera",
            };
            err(at.into(), e.to_string())
        })?;

        let mut names: HashMap<&str, u32> = HashMap::new();
        let mut materials = vec![Material::default()];
        for (name, m) in &desc.materials {
            let at = |key: &str| format!("materials.{name}.{key}");
            color(at("ambient"), m.ambient)?;
            color(at("diffuse"), m.diffuse)?;
            color(at("specular"), m.specular)?;
            match m.mirror {
                crate::desc::Rgb::Grey(g) => amount(at("mirror"), g)?,
                crate::desc::Rgb::Rgb(c) => color(at("mirror"), c)?,
            }
            amount(at("shininess"), m.shininess)?;
            names.insert(name, materials.len() as u32);
            materials.push(Material {
                ambient: v3(m.ambient),
                diffuse: v3(m.diffuse),
                specular: v3(m.specular),
                shininess: m.shininess,
                mirror: v3(m.mirror.rgb()),
            });
        }
        let material = |m: &Option<String>, path: String| -> Result<u32, SceneError> {
            match m {
                None => Ok(0),
                Some(n) => names.get(n.as_str()).copied().ok_or_else(|| {
                    let known: Vec<&str> = names.keys().copied().collect();
                    err(
                        path,
                        format!(
                            "unknown material '{n}' (defined: {})",
                            if known.is_empty() {
                                "none".into()
                            } else {
                                known.join(", ")
                            }
                        ),
                    )
                }),
            }
        };

        let (mut ambient, mut lights) = (Vec3::ZERO, Vec::new());
        for (i, l) in desc.lights.iter().enumerate() {
            let at = |key: &str| format!("lights[{i}].{key}");
            let (LightDesc::Ambient(AmbientDesc {
                color: c,
                intensity,
                ..
            })
            | LightDesc::Point(PointDesc {
                color: c,
                intensity,
                ..
            })
            | LightDesc::Directional(DirectionalDesc {
                color: c,
                intensity,
                ..
            })) = l;
            color(at("color"), *c)?;
            amount(at("intensity"), *intensity)?;
            match l {
                LightDesc::Point(p) => point(at("position"), p.position)?,
                LightDesc::Directional(d) => point(at("direction"), d.direction)?,
                LightDesc::Ambient(_) => {}
            }
            match l {
                LightDesc::Ambient(AmbientDesc {
                    color, intensity, ..
                }) => ambient += v3(*color) * *intensity,
                LightDesc::Point(PointDesc {
                    position,
                    color,
                    intensity,
                    ..
                }) => lights.push(Light::Point(v3(*position), v3(*color) * *intensity)),
                LightDesc::Directional(DirectionalDesc {
                    direction,
                    color,
                    intensity,
                    ..
                }) => {
                    let d = v3(*direction).try_normalize().ok_or_else(|| {
                        err(format!("lights[{i}].direction"), "zero direction".into())
                    })?;
                    lights.push(Light::Directional(-d, v3(*color) * *intensity));
                }
            }
        }

        let start = Instant::now();
        let mut objects = Vec::new();
        let mut meshes = Vec::new();
        let mut instances = Vec::new();
        let mut infos = Vec::new();
        let mut loaded: HashMap<&str, u32> = HashMap::new();
        let mut shapes = Vec::new();
        let mut shape_materials = Vec::new();
        let mut triangles = 0usize;
        // Mesh files some surface shades smooth: only they need normals.
        let smooth_files: HashSet<&str> = desc
            .surfaces
            .iter()
            .filter_map(|s| match s {
                SurfaceDesc::Mesh(m) if m.shading == Shading::Smooth => Some(m.file.as_str()),
                _ => None,
            })
            .collect();
        for (i, s) in desc.surfaces.iter().enumerate() {
            let at = |field: &str| format!("surfaces[{i}].{field}");
            match s {
                SurfaceDesc::Sphere(SphereDesc {
                    center,
                    radius,
                    material: m,
                    ..
                }) => {
                    point(at("center"), *center)?;
                    if !(*radius > 0.0 && radius.is_finite()) {
                        return Err(err(
                            at("radius"),
                            format!(
                                "a sphere needs a finite centre and a positive radius, got {}",
                                shown(*radius)
                            ),
                        ));
                    }
                    shapes.push(Shape::Sphere(Sphere::new(v3(*center), *radius)));
                    shape_materials.push(material(m, at("material"))?);
                }
                SurfaceDesc::Triangle(TriangleDesc {
                    vertices,
                    material: m,
                    ..
                }) => {
                    for (k, &p) in vertices.iter().enumerate() {
                        point(at(&format!("vertices[{k}]")), p)?;
                    }
                    shapes.push(Shape::Triangle(vertices.map(v3)));
                    shape_materials.push(material(m, at("material"))?);
                    triangles += 1;
                }
                SurfaceDesc::Mesh(MeshDesc {
                    file: mesh_file,
                    material: m,
                    shading,
                    transform: t,
                    instances: many,
                    ..
                }) => {
                    let mat = material(m, at("material"))?;
                    let object = match loaded.get(mesh_file.as_str()) {
                        Some(&o) => o,
                        None => {
                            let mut mesh = load_mesh(mesh_file).map_err(|e| err(at("file"), e))?;
                            let normals = smooth_files
                                .contains(mesh_file.as_str())
                                .then(|| encoded_vertex_normals(&mesh));
                            // The polygons go before the build: only the
                            // triangles and positions are needed from here.
                            let tris = mesh.triangles();
                            let positions = std::mem::take(&mut mesh.positions);
                            drop(mesh);
                            let tm = TriangleMesh::new(positions, tris);
                            let scene = Scene::from_mesh_with(&tm, accel, &config);
                            objects.push(Object::Mesh(scene));
                            let TriangleMesh {
                                positions,
                                triangles: tris,
                            } = tm;
                            drop(positions);
                            meshes.push(MeshData {
                                triangles: tris.len(),
                                corner_normals: normals
                                    .map_or_else(Vec::new, |n| corner_normals(tris, &n)),
                            });
                            let o = (objects.len() - 1) as u32;
                            loaded.insert(mesh_file, o);
                            o
                        }
                    };
                    let placements: Vec<&TransformDesc> = match many {
                        Some(list) => list.iter().collect(),
                        None => vec![t],
                    };
                    for p in placements {
                        instances.push(Instance {
                            object,
                            transform: transform(p),
                        });
                        infos.push(InstanceInfo {
                            material: mat,
                            smooth: *shading == Shading::Smooth,
                        });
                        triangles += meshes[object as usize].triangles;
                    }
                }
            }
        }
        if !shapes.is_empty() {
            objects.push(Object::Shapes(Scene::build(Shapes(shapes), accel)));
            instances.push(Instance {
                object: (objects.len() - 1) as u32,
                transform: Mat4::IDENTITY,
            });
            infos.push(InstanceInfo {
                material: 0,
                smooth: false,
            });
        }
        let scene =
            Instances::build(objects, &instances, accel).map_err(|e| err("surfaces".into(), e))?;
        let build_ms = start.elapsed().as_secs_f64() * 1e3;
        let b = scene.bounds();
        // A hundred-thousandth of the scene, with no floor of its own: at
        // least 1e-6 put shadow rays of a scene smaller than 0.1 units that
        // far off the surface (a 1e-15 scene came out speckled). A scene
        // of one point takes 1e-4.
        let diagonal = b.diagonal();
        let epsilon = if !b.is_empty() && diagonal > 0.0 && diagonal.is_finite() {
            (diagonal * 1e-5).max(f32::MIN_POSITIVE)
        } else {
            1e-4
        };
        Ok(Self {
            camera,
            width: img.width,
            height: img.height,
            spp: img.spp,
            background: v3(img.background),
            max_depth: desc.max_depth,
            ambient,
            lights,
            materials,
            scene,
            meshes,
            instances: infos,
            shape_materials,
            triangles,
            accel,
            build_ms,
            epsilon,
        })
    }

    /// What the world keeps in memory to trace and shade, for reports.
    #[must_use]
    pub fn bytes(&self) -> WorldBytes {
        let mut b = WorldBytes {
            structure: self.scene.top_stats().bytes,
            shading: self.shape_materials.len() * 4,
            triangles: 0,
        };
        for o in self.scene.objects() {
            b.structure += match o {
                Object::Mesh(s) => s.stats().bytes + s.prims().bytes(),
                Object::Shapes(s) => s.stats().bytes + std::mem::size_of_val(&s.prims().0[..]),
            };
        }
        for m in &self.meshes {
            b.shading += std::mem::size_of_val(&m.corner_normals[..]);
            b.triangles += m.triangles;
        }
        b
    }

    /// The whole scene as one surface.
    #[must_use]
    pub fn surface(&self) -> &dyn Surface {
        &self.scene
    }

    /// Material and shading normal (world space, unnormalized orientation) at a hit.
    fn shade_info(&self, hit: &Hit) -> (Material, Vec3) {
        let info = self.instances[hit.instance as usize];
        match &self.scene.objects()[self.scene.object_of(hit.instance) as usize] {
            Object::Mesh(_) => {
                let m = &self.meshes[self.scene.object_of(hit.instance) as usize];
                let n = if info.smooth && !m.corner_normals.is_empty() {
                    let [a, b, c] = m.corner_normals[hit.prim as usize].map(decode_unit);
                    let n = (1.0 - hit.u - hit.v) * a + hit.u * b + hit.v * c;
                    let n = self.scene.normal_to_world(hit.instance, n);
                    if n == Vec3::ZERO {
                        hit.normal
                    } else {
                        n
                    }
                } else {
                    hit.normal
                };
                (self.materials[info.material as usize], n)
            }
            Object::Shapes(_) => (
                self.materials[self.shape_materials[hit.prim as usize] as usize],
                hit.normal,
            ),
        }
    }

    /// Radiance arriving along `ray` (Whitted: ambient, Lambert and
    /// Blinn-Phong per unshadowed light, and mirror reflection up to
    /// `max_depth` bounces). Counts traced rays in `rays`.
    pub fn trace(&self, ray: &Ray, depth: u32, rays: &mut u64) -> Vec3 {
        *rays += 1;
        let hit = self.scene.intersect(ray);
        self.shade(ray, hit, depth, rays)
    }

    /// [`Self::trace`] of eight camera rays, whose closest hits are found
    /// together as a packet ([`Surface::intersect8`]), and whose shadow
    /// rays toward each light are tested together too
    /// ([`Surface::occluded8`]): the same answers, so the same image,
    /// faster for a camera's neighbouring rays. Mirror reflections are
    /// traced one by one.
    pub fn trace8(&self, camera: &[Ray; LANES], rays: &mut u64) -> [Vec3; LANES] {
        *rays += LANES as u64;
        let hits = self.scene.intersect8(camera);
        let points: [Option<ShadePoint>; LANES] =
            std::array::from_fn(|i| hits[i].map(|h| self.shade_point(&camera[i], &h)));
        // The sums in `shade`'s order: ambient, each light in turn, mirror.
        let mut color: [Vec3; LANES] = std::array::from_fn(|i| match &points[i] {
            Some(sp) => sp.mat.ambient * self.ambient,
            None => self.background,
        });
        for light in &self.lights {
            let shadows: [Option<LightRay>; LANES] =
                std::array::from_fn(|i| points[i].as_ref().and_then(|sp| sp.toward(light)));
            let active = (0..LANES).fold(0u32, |m, i| m | u32::from(shadows[i].is_some()) << i);
            if active == 0 {
                continue;
            }
            *rays += u64::from(active.count_ones());
            // A lane without a shadow ray repeats one that has, its answer
            // unused, so that the eight still make a packet.
            let first = shadows[active.trailing_zeros() as usize].map(|s| s.ray);
            let blocked = match first {
                Some(r) if active.count_ones() > 1 => {
                    let batch = std::array::from_fn(|i| shadows[i].map_or(r, |s| s.ray));
                    self.scene.occluded8(&batch)
                }
                _ => {
                    std::array::from_fn(|i| shadows[i].is_some_and(|s| self.scene.occluded(&s.ray)))
                }
            };
            for i in 0..LANES {
                if let (Some(sp), Some(s)) = (&points[i], &shadows[i]) {
                    if !blocked[i] {
                        sp.add_lit(s, &mut color[i]);
                    }
                }
            }
        }
        for i in 0..LANES {
            if let Some(sp) = &points[i] {
                if let Some(m) = self.mirror(&camera[i], sp, 0, rays) {
                    color[i] += m;
                }
            }
        }
        color
    }

    /// [`Self::trace`] of each ray of `stream` at `depth` (a tile's camera
    /// rays at 0), traced as streams: their closest hits together
    /// ([`Surface::intersect_stream`]), then each light's shadow rays
    /// ([`Surface::occluded_stream`]), then the mirror reflections as the
    /// next depth's stream. The same answers as one by one, so the same
    /// radiance, bit for bit, and the same rays counted; a stream whose
    /// coherent runs make packets or groups (a camera's rays in 4 × 2
    /// pixel blocks, shadow rays toward one light) is traced faster.
    pub fn trace_stream(&self, stream: &[Ray], depth: u32, rays: &mut u64) -> Vec<Vec3> {
        *rays += stream.len() as u64;
        let mut hits = vec![None; stream.len()];
        self.scene.intersect_stream(stream, &mut hits);
        let points: Vec<Option<ShadePoint>> = stream
            .iter()
            .zip(&hits)
            .map(|(r, h)| h.map(|h| self.shade_point(r, &h)))
            .collect();
        // The sums in `shade`'s order: ambient, each light in turn, mirror.
        let mut color: Vec<Vec3> = points
            .iter()
            .map(|sp| match sp {
                Some(sp) => sp.mat.ambient * self.ambient,
                None => self.background,
            })
            .collect();
        let (mut lit, mut shadow, mut blocked) = (Vec::new(), Vec::new(), Vec::new());
        for light in &self.lights {
            lit.clear();
            for (i, sp) in points.iter().enumerate() {
                if let Some(s) = sp.as_ref().and_then(|sp| sp.toward(light)) {
                    lit.push((i, s));
                }
            }
            *rays += lit.len() as u64;
            shadow.clear();
            shadow.extend(lit.iter().map(|(_, s)| s.ray));
            blocked.clear();
            blocked.resize(shadow.len(), false);
            self.scene.occluded_stream(&shadow, &mut blocked);
            for ((i, s), &b) in lit.iter().zip(&blocked) {
                if let (false, Some(sp)) = (b, &points[*i]) {
                    sp.add_lit(s, &mut color[*i]);
                }
            }
        }
        let (which, bounced): (Vec<usize>, Vec<Ray>) = points
            .iter()
            .enumerate()
            .filter_map(|(i, sp)| Some((i, self.reflected(&stream[i], sp.as_ref()?, depth)?)))
            .unzip();
        if !bounced.is_empty() {
            let radiance = self.trace_stream(&bounced, depth + 1, rays);
            for (&i, r) in which.iter().zip(radiance) {
                if let Some(sp) = &points[i] {
                    color[i] += sp.mat.mirror * r;
                }
            }
        }
        color
    }

    /// The radiance `ray` brings back from `hit` (the background on a miss).
    fn shade(&self, ray: &Ray, hit: Option<Hit>, depth: u32, rays: &mut u64) -> Vec3 {
        let Some(hit) = hit else {
            return self.background;
        };
        let sp = self.shade_point(ray, &hit);
        let mut color = sp.mat.ambient * self.ambient;
        for light in &self.lights {
            let Some(s) = sp.toward(light) else {
                continue;
            };
            *rays += 1;
            if !self.scene.occluded(&s.ray) {
                sp.add_lit(&s, &mut color);
            }
        }
        if let Some(m) = self.mirror(ray, &sp, depth, rays) {
            color += m;
        }
        color
    }

    /// What shading `hit` of `ray` needs before its lights.
    fn shade_point(&self, ray: &Ray, hit: &Hit) -> ShadePoint {
        let (mat, mut n) = self.shade_info(hit);
        let mut ng = hit.normal;
        let view = -ray.dir().normalize();
        // Shade the side the ray came from.
        if ng.dot(view) < 0.0 {
            ng = -ng;
            n = -n;
        }
        if n.dot(view) < 0.0 {
            n = ng;
        }
        let hp = ray.at(hit.t);
        // Leave the surface by a little more than rounding can move a hit point.
        let p = hp + ng * self.epsilon.max(hp.abs().max_element() * 1e-6);
        ShadePoint {
            mat,
            n,
            ng,
            view,
            p,
        }
    }

    /// The mirror reflection's radiance at `sp` (traced one by one), if
    /// its material reflects and `depth` allows another bounce.
    fn mirror(&self, ray: &Ray, sp: &ShadePoint, depth: u32, rays: &mut u64) -> Option<Vec3> {
        let r = self.reflected(ray, sp, depth)?;
        Some(sp.mat.mirror * self.trace(&r, depth + 1, rays))
    }

    /// The mirror reflection of `ray` at `sp`, if its material reflects
    /// and `depth` allows another bounce.
    fn reflected(&self, ray: &Ray, sp: &ShadePoint, depth: u32) -> Option<Ray> {
        if sp.mat.mirror == Vec3::ZERO || depth >= self.max_depth {
            return None;
        }
        let d = ray.dir().normalize();
        let r = d - 2.0 * d.dot(sp.n) * sp.n;
        Some(Ray::infinite(sp.p, r))
    }

    /// Nodes visited plus primitives tested by the camera ray.
    pub fn cost(&self, ray: &Ray) -> u64 {
        let mut c = CountStats::default();
        self.scene.intersect_count(ray, &mut c);
        c.nodes + c.prims
    }
}
