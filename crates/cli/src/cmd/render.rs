//! `raymesh render [SCENE.json | MESH] [-o OUT.png] [--accel NAME] [--spatial-splits [FRACTION]] [--width W] [--height H] [--spp N] [--threads N] [--heatmap]`.

use anyhow::{bail, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use raymesh_accel::AccelKind;
use raymesh_geometry::Vec3;
use raymesh_mesh::io::{read_mesh, Format};
use raymesh_render::{
    demo_scene, heat_color, render, save_png, to_srgb8, torus_knot, Mode, Options, SceneDesc, World,
};
use serde_json::json;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};

/// Arguments of `raymesh render`.
#[derive(clap::Args)]
pub struct Args {
    /// A scene (.json, see docs/scene-format.md) or a mesh (.obj, .off, .ply, .stl);
    /// none renders the built-in demo scene.
    pub input: Option<PathBuf>,
    /// Output PNG. Without it the image goes to raymesh.png (demo) or NAME.png,
    /// and an existing file there is never overwritten: a free name is chosen.
    #[arg(short = 'o', long = "output", visible_alias = "out")]
    pub output: Option<PathBuf>,
    /// Acceleration structure (overrides the scene's).
    #[arg(long)]
    pub accel: Option<AccelKind>,
    /// Spatial splits for the meshes' bvh-binned, bvh4 and bvh8 (overrides
    /// the scene's `spatial_splits`): up to FRACTION more references than
    /// triangles, 0.25 when given alone; for scenes of long thin triangles.
    #[arg(long, allow_negative_numbers = true, value_name = "FRACTION", num_args = 0..=1, default_missing_value = "0.25",
          value_parser = crate::cmd::parse_fraction)]
    pub spatial_splits: Option<f32>,
    /// Reinsertion optimization of the meshes' BVHs (sets the scene's
    /// `optimize`; as `raycast --optimize`).
    #[arg(long)]
    pub optimize: bool,
    /// Image width (overrides the scene's).
    #[arg(long, allow_negative_numbers = true)]
    pub width: Option<u32>,
    /// Image height (overrides the scene's).
    #[arg(long, allow_negative_numbers = true)]
    pub height: Option<u32>,
    /// Samples per pixel (overrides the scene's).
    #[arg(long, allow_negative_numbers = true)]
    pub spp: Option<u32>,
    /// Worker threads, 1 to 1024 (default: all cores).
    #[arg(long, allow_negative_numbers = true)]
    pub threads: Option<usize>,
    /// Show what each pixel's camera rays cost (nodes visited + primitives tested) instead of shading.
    #[arg(long)]
    pub heatmap: bool,
}

/// A procedural mesh by name (`builtin:NAME` in scene files).
fn builtin(name: &str) -> Option<raymesh_mesh::IndexedMesh> {
    match name {
        "torus-knot" => Some(torus_knot(640, 48)),
        _ => None,
    }
}

/// Resolves a scene's mesh path: `builtin:NAME`, or a file relative to the
/// scene. A file's error keeps its cause (`cannot read: No such file or
/// directory`), which the error's own text leaves to its source.
fn mesh_loader(base: PathBuf) -> impl Fn(&str) -> Result<raymesh_mesh::IndexedMesh, String> {
    move |file: &str| {
        if let Some(name) = file.strip_prefix("builtin:") {
            return builtin(name)
                .ok_or_else(|| format!("no built-in mesh '{name}' (there is: torus-knot)"));
        }
        read_mesh(base.join(file)).map_err(|e| format!("{:#}", anyhow::Error::from(e)))
    }
}

/// A scene made on the spot for a mesh: BENCH.md's camera, a light near
/// the eye, a grey material and a floor under the mesh.
fn mesh_scene(path: &Path) -> Result<SceneDesc> {
    let mesh = crate::cmd::read_mesh(path)?;
    let b = mesh.bounds();
    if b.is_empty() {
        bail!("{}: the mesh has no vertices", path.display());
    }
    // The diagonal in f64 for the message below (past 1e38 it is not an
    // f32); in f32 for the scene, from `Aabb::diagonal` (its bits).
    let diagonal = (b.max.as_dvec3() - b.min.as_dvec3()).length();
    let d = b.diagonal();
    let (c, d) = (b.centroid(), if d > 0.0 { d } else { 1e-6 });
    let eye = c + Vec3::new(1.0, 0.6, 1.6).normalize() * d;
    let light = eye + 0.5 * d * Vec3::Y + Vec3::new(-0.3, 0.0, 0.2) * d;
    let (y, r) = (b.min.y - 1e-3 * d, 4.0 * d);
    let corner = |sx: f32, sz: f32| [c.x + sx * r, y, c.z + sz * r];
    // The light's intensity grows with the square of the mesh's size (its
    // falloff is the square of the distance), and the floor reaches four
    // sizes out: past about 1e18 units across these overflow f32, and
    // below 1e-18 the square underflows (the image came out black). Say
    // so rather than render a wrong picture.
    let intensity = 1.6 * d * d;
    let far = [corner(-1.0, -1.0), corner(1.0, 1.0)];
    if !(intensity.is_normal()
        && intensity < 1e37
        && eye.is_finite()
        && light.is_finite()
        && far.iter().flatten().all(|x| x.is_finite()))
    {
        bail!(
            "{}: the mesh is {diagonal:.1e} units across, too {} for the scene `render` makes around a mesh \
             (light and floor scaled to it, in f32: from about 1e-18 to 1e18 units); \
             scale it, or write a scene file (docs/scene-format.md)",
            path.display(),
            if diagonal > 1.0 { "large" } else { "small" }
        );
    }
    let desc = json!({
        "camera": { "eye": eye.to_array(), "target": c.to_array(), "fov": 40 },
        "image": { "width": 800, "height": 600, "spp": 4 },
        "lights": [
            { "type": "ambient", "intensity": 0.2 },
            { "type": "point", "position": light.to_array(), "intensity": intensity }
        ],
        "materials": {
            "grey": { "ambient": [0.5, 0.5, 0.5], "diffuse": [0.7, 0.7, 0.7], "specular": [0.2, 0.2, 0.2], "shininess": 30 },
            "floor": { "ambient": [0.4, 0.4, 0.42], "diffuse": [0.5, 0.5, 0.52] }
        },
        "surfaces": [
            { "type": "mesh", "file": path.file_name().unwrap_or_default().to_string_lossy(), "material": "grey" },
            { "type": "triangle", "vertices": [corner(-1.0, -1.0), corner(-1.0, 1.0), corner(1.0, 1.0)], "material": "floor" },
            { "type": "triangle", "vertices": [corner(-1.0, -1.0), corner(1.0, 1.0), corner(1.0, -1.0)], "material": "floor" }
        ]
    });
    Ok(SceneDesc::parse(&desc.to_string(), path)?)
}

/// `stem.png`, or the first of `stem-1.png`, `stem-2.png`, … that does not exist.
fn free_name(stem: &str) -> PathBuf {
    let first = PathBuf::from(format!("{stem}.png"));
    if !first.exists() {
        return first;
    }
    (1..)
        .map(|i| PathBuf::from(format!("{stem}-{i}.png")))
        .find(|p| !p.exists())
        .expect("some name is free")
}

/// Runs the command.
pub fn run(args: &Args) -> Result<()> {
    // The flags given together contradict each other (a scene file's
    // settings apply to its meshes' BVHs and are documented so).
    if let Some(a) = args.accel {
        crate::cmd::check_build_flags(a, args.spatial_splits.is_some(), args.optimize)?;
    }
    let pool = crate::cmd::thread_pool(args.threads)?;
    let (mut desc, file, base, stem) = match &args.input {
        None => (
            demo_scene(),
            PathBuf::from("<demo>"),
            PathBuf::from("."),
            "raymesh".to_string(),
        ),
        Some(p) => {
            let stem = p
                .file_stem()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned();
            let base = p.parent().map(Path::to_path_buf).unwrap_or_default();
            let is_json = p
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("json"));
            if is_json {
                (SceneDesc::load(p)?, p.clone(), base, stem)
            } else if Format::from_extension(p).is_some() {
                (mesh_scene(p)?, p.clone(), base, stem)
            } else {
                bail!(
                    "{}: expected a scene (.json) or a mesh (.obj, .off, .ply, .stl)",
                    p.display()
                );
            }
        }
    };
    if let Some(a) = args.accel {
        desc.accel = a.name().to_string();
    }
    if let Some(f) = args.spatial_splits {
        desc.spatial_splits = f;
    }
    if args.optimize {
        desc.optimize = true;
    }
    if let Some(w) = args.width {
        desc.image.width = w;
    }
    if let Some(h) = args.height {
        desc.image.height = h;
    }
    if let Some(s) = args.spp {
        desc.image.spp = s;
    }
    let out = match &args.output {
        Some(o) => o.clone(),
        None => free_name(
            if args.heatmap {
                format!("{stem}-heatmap")
            } else {
                stem
            }
            .as_str(),
        ),
    };
    // The scene or mesh given, and the mesh files a scene names.
    let mut inputs = Vec::new();
    if let Some(input) = &args.input {
        let scene = input
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"));
        let what = if scene { "scene" } else { "mesh" };
        inputs.push((what, input.clone()));
        for s in &desc.surfaces {
            if let raymesh_render::SurfaceDesc::Mesh(m) = s {
                if !m.file.starts_with("builtin:") {
                    inputs.push(("mesh", base.join(&m.file)));
                }
            }
        }
    }
    let inputs: Vec<(&str, &Path)> = inputs.iter().map(|(w, p)| (*w, p.as_path())).collect();
    crate::cmd::check_output(&out, &inputs)?;
    // Checked before the render, which would otherwise run to its end and
    // then fail to write.
    if !out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"))
    {
        bail!("{}: render writes PNG images (.png)", out.display());
    }
    let step = crate::cmd::stage("reading meshes and building structures".to_string());
    let world = pool.install(|| World::build(&desc, &file, &mesh_loader(base)))?;
    step.finish_and_clear();
    let bar = if std::io::stderr().is_terminal() {
        let b = ProgressBar::new(1);
        b.set_style(
            ProgressStyle::with_template(
                "{spinner} rendering [{bar:40}] {percent}% {elapsed} (eta {eta})",
            )?
            .progress_chars("=> "),
        );
        b
    } else {
        ProgressBar::hidden()
    };
    let mode = if args.heatmap {
        Mode::Heatmap
    } else {
        Mode::Shade
    };
    let img = pool.install(|| {
        render(&world, Options { mode }, &|done, total| {
            bar.set_length(total);
            bar.set_position(done);
        })
    });
    bar.finish_and_clear();
    let bytes = if args.heatmap {
        let costs: Vec<f32> = img.pixels.iter().map(|p| p.x).collect();
        let lo = costs.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = costs.iter().copied().fold(0.0f32, f32::max);
        // Logarithmic: silhouettes cost hundreds of steps where open space
        // costs a few; a linear scale would show only the silhouettes.
        let span = (1.0 + hi - lo).ln().max(1e-6);
        // The bottom 12 rows show the palette from the minimum (left) to the maximum (right).
        let legend = 12.min(img.height / 8);
        let pixels: Vec<Vec3> = (0..img.pixels.len())
            .map(|i| {
                let (x, y) = (i as u32 % img.width, i as u32 / img.width);
                if y >= img.height - legend {
                    heat_color(x as f32 / (img.width - 1).max(1) as f32)
                } else {
                    heat_color((1.0 + costs[i] - lo).ln() / span)
                }
            })
            .collect();
        println!("heat map: cost per camera ray (nodes visited + primitives tested) from {lo:.1} (dark) to {hi:.1} (bright), logarithmic; the strip at the bottom is the scale");
        to_srgb8(&pixels)
    } else {
        to_srgb8(&img.pixels)
    };
    save_png(&out, img.width, img.height, &bytes)
        .with_context(|| format!("{}: cannot write", out.display()))?;
    println!(
        "{} triangles, {} ({} threads): build {:.1} ms, render {:.2} s, {} rays, {:.2} Mrays/s",
        world.triangles,
        world.accel,
        pool.current_num_threads(),
        world.build_ms,
        img.seconds,
        img.rays,
        img.rays as f64 / img.seconds.max(1e-9) / 1e6
    );
    let mem = world.bytes();
    let mib = |b: usize| b as f64 / (1 << 20) as f64;
    let per_tri = |b: usize| {
        if mem.triangles > 0 {
            format!(" ({:.1} bytes/triangle)", b as f64 / mem.triangles as f64)
        } else {
            String::new()
        }
    };
    println!(
        "memory: structure {:.1} MiB{} + shading {:.1} MiB{}",
        mib(mem.structure),
        per_tri(mem.structure),
        mib(mem.shading),
        per_tri(mem.shading),
    );
    println!(
        "wrote {} ({}×{}, {} spp)",
        out.display(),
        img.width,
        img.height,
        world.spp
    );
    Ok(())
}
