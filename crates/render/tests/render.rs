//! Renderer tests: every structure renders the same image, analytic
//! checks of coverage and radiance, and scene errors with their places.

use raymesh_accel::AccelKind;
use raymesh_geometry::Vec3;
use raymesh_render::{render, Mode, Options, SceneDesc, World};
use std::path::Path;

/// The mesh a scene names: the built-in knot at `knot` (segments, sides),
/// else a file of `tests/data`.
fn load_mesh(name: &str, knot: (u32, u32)) -> Result<raymesh_mesh::IndexedMesh, String> {
    if name == "builtin:torus-knot" {
        Ok(raymesh_render::torus_knot(knot.0, knot.1))
    } else {
        raymesh_mesh::io::read_mesh(
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../tests/data")
                .join(name),
        )
        .map_err(|e| e.to_string())
    }
}

fn world(json: &str) -> World {
    let desc = SceneDesc::parse(json, Path::new("test.json")).unwrap_or_else(|e| panic!("{e}"));
    World::build(&desc, Path::new("test.json"), &|name| {
        load_mesh(name, (64, 12))
    })
    .unwrap_or_else(|e| panic!("{e}"))
}

fn shade(w: &World) -> Vec<Vec3> {
    render(w, Options { mode: Mode::Shade }, &|_, _| {}).pixels
}

#[test]
fn every_structure_renders_the_same_image() {
    let mut desc = raymesh_render::demo_scene();
    desc.image.width = 96;
    desc.image.height = 72;
    desc.image.spp = 2;
    // A real mesh with holes, instanced, beside the demo's knot.
    {
        let surfaces = &mut desc.surfaces;
        let extra = r#"{"type": "mesh", "file": "elephant-with-holes.off", "shading": "flat",
            "instances": [{"translate": [3, 0.5, 2], "scale": 1.5}, {"translate": [-3, 0.5, 2], "rotate": [0, 90, 0], "scale": 1.5}]}"#;
        surfaces.push(serde_json::from_str(extra).unwrap());
    }
    let mut reference: Option<Vec<Vec3>> = None;
    // Every structure, then the BVHs that take spatial splits with them.
    let spatial = [AccelKind::BvhBinned, AccelKind::Bvh8];
    let builds = AccelKind::ALL
        .map(|k| (k, 0.0))
        .into_iter()
        .chain(spatial.map(|k| (k, 1.0)));
    for (kind, splits) in builds {
        desc.accel = kind.name().to_string();
        desc.spatial_splits = splits;
        let w = World::build(&desc, Path::new("demo"), &|name| load_mesh(name, (96, 16))).unwrap();
        let img = shade(&w);
        match &reference {
            None => reference = Some(img),
            Some(r) => {
                let same = r
                    .iter()
                    .zip(&img)
                    .all(|(a, b)| a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits));
                assert!(
                    same,
                    "{kind} (spatial splits {splits}) renders another image than brute force"
                );
            }
        }
    }
}

/// Eight camera rays traced together (`trace8`: the hits and then each
/// light's shadow rays as packets), and a stream of them (`trace_stream`),
/// give each ray's radiance bit for bit and count the same rays as
/// tracing them one by one, over a mesh and
/// its instances under a structure that takes packets and one that does
/// not (the grid, whose packets go one by one; brute force, in its place
/// before, made this one test 17 s of the file's 19); with several lanes
/// shadowed, some lit, some missing everything.
#[test]
fn packets_shade_as_one_by_one() {
    let mut desc = raymesh_render::demo_scene();
    let extra = r#"{"type": "mesh", "file": "elephant-with-holes.off", "shading": "flat",
        "instances": [{"translate": [3, 0.5, 2], "scale": 1.5}, {"translate": [-3, 0.5, 2], "rotate": [0, 90, 0], "scale": 1.5}]}"#;
    desc.surfaces.push(serde_json::from_str(extra).unwrap());
    let (w, h) = (64u32, 48u32);
    for kind in [AccelKind::Bvh8, AccelKind::Grid] {
        desc.accel = kind.name().to_string();
        let world =
            World::build(&desc, Path::new("demo"), &|name| load_mesh(name, (96, 16))).unwrap();
        let (mut background, mut lit) = (0, 0);
        let mut stream = Vec::new();
        for by in (0..h).step_by(2) {
            for bx in (0..w).step_by(4) {
                let rays: [_; 8] = std::array::from_fn(|i| {
                    let (x, y) = (bx + i as u32 % 4, by + i as u32 / 4);
                    let (sx, sy) = ((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32);
                    world.camera.ray(sx, sy)
                });
                stream.extend(rays);
                let (mut n8, mut n1) = (0u64, 0u64);
                let got = world.trace8(&rays, &mut n8);
                for (i, r) in rays.iter().enumerate() {
                    let want = world.trace(r, 0, &mut n1);
                    let bits = |v: Vec3| v.to_array().map(f32::to_bits);
                    assert_eq!(
                        bits(got[i]),
                        bits(want),
                        "{kind}: block ({bx}, {by}), lane {i}"
                    );
                    background += usize::from(want == world.background);
                    lit += usize::from(want != world.background);
                }
                assert_eq!(n8, n1, "{kind}: rays counted, block ({bx}, {by})");
            }
        }
        assert!(
            background > 100 && lit > 1000,
            "{kind}: {background} background, {lit} lit"
        );
        // The whole image's camera rays as one stream (`trace_stream`:
        // the hits, each light's shadow rays, then the mirror bounces as
        // streams), and as streams of 200.
        let (mut one, mut n1) = (Vec::new(), 0u64);
        for r in &stream {
            one.push(world.trace(r, 0, &mut n1));
        }
        let bits = |v: &Vec3| v.to_array().map(f32::to_bits);
        for size in [stream.len(), 200] {
            let mut ns = 0u64;
            let got: Vec<Vec3> = stream
                .chunks(size)
                .flat_map(|c| world.trace_stream(c, 0, &mut ns))
                .collect();
            for (i, (g, o)) in got.iter().zip(&one).enumerate() {
                assert_eq!(bits(g), bits(o), "{kind}: streams of {size}, ray {i}");
            }
            assert_eq!(ns, n1, "{kind}: rays counted, streams of {size}");
        }
        assert!(
            n1 > 2 * stream.len() as u64,
            "{kind}: few shadow and mirror rays"
        );
    }
}

#[test]
fn a_sphere_covers_the_disc_it_must() {
    // Camera at distance D looking at a sphere of radius r: its silhouette is
    // a disc of angular radius asin(r / D).
    let (d, r, fov, size) = (10.0f32, 2.0f32, 40.0f32, 201u32);
    let w = world(&format!(
        r#"{{"camera": {{"eye": [0, 0, {d}], "target": [0, 0, 0], "fov": {fov}}},
            "image": {{"width": {size}, "height": {size}, "spp": 1, "background": [0, 0, 0]}},
            "lights": [{{"type": "ambient"}}],
            "materials": {{"white": {{"ambient": [1, 1, 1], "diffuse": [0, 0, 0]}}}},
            "surfaces": [{{"type": "sphere", "center": [0, 0, 0], "radius": {r}, "material": "white"}}]}}"#
    ));
    let img = shade(&w);
    let covered = img.iter().filter(|p| p.x > 0.5).count() as f32;
    let alpha = (r / d).asin();
    let half = (fov.to_radians() / 2.0).tan();
    let disc_px = alpha.tan() / half * size as f32 / 2.0;
    let expected = std::f32::consts::PI * disc_px * disc_px;
    assert!(
        (covered - expected).abs() / expected < 0.02,
        "{covered} pixels, expected {expected}"
    );
    // Unlit by anything but ambient 1 × reflectance 1: exactly 1.
    assert_eq!(img[(size * size / 2) as usize], Vec3::ONE);
}

#[test]
fn a_lambert_plane_has_the_radiance_it_must() {
    // Point light of intensity I at height h above the plane point seen in
    // the image centre: irradiance I / h², radiance kd · I / h² (cos = 1).
    let (h, intensity, kd) = (2.0f32, 8.0f32, 0.5f32);
    let w = world(&format!(
        r#"{{"camera": {{"eye": [0, 5, 0.001], "target": [0, 0, 0], "up": [0, 0, -1], "fov": 30}},
            "image": {{"width": 33, "height": 33, "spp": 1}},
            "lights": [{{"type": "point", "position": [0, {h}, 0], "intensity": {intensity}}}],
            "materials": {{"m": {{"ambient": [0, 0, 0], "diffuse": [{kd}, {kd}, {kd}]}}}},
            "surfaces": [
              {{"type": "triangle", "vertices": [[-10, 0, -10], [-10, 0, 10], [10, 0, 10]], "material": "m"}},
              {{"type": "triangle", "vertices": [[-10, 0, -10], [10, 0, 10], [10, 0, -10]], "material": "m"}}]}}"#
    ));
    let img = shade(&w);
    let centre = img[(33 * 16 + 16) as usize];
    let expected = kd * intensity / (h * h);
    assert!(
        (centre.x - expected).abs() < 1e-3 * expected,
        "{centre} vs {expected}"
    );
    // Farther from the light's foot, cos θ / r² falls off.
    assert!(img[(33 * 16) as usize].x < centre.x);
}

#[test]
fn shadows_fall_where_they_must() {
    // Light at (0, 4, 0), sphere of radius 0.2 at (0.4, 2, 0): its shadow
    // covers x in [0.4, 1.2] on the plane. The camera looks straight down
    // from y = 5 with +x to the right; the sphere hides the shadow's near
    // part, and x ≈ 1.06 (column 30 of 33, 16.5 columns per 5 tan 15°) is
    // plane in shadow.
    let w = world(
        r#"{"camera": {"eye": [0, 5, 0.001], "target": [0, 0, 0], "up": [0, 0, -1], "fov": 30},
            "image": {"width": 33, "height": 33, "spp": 1},
            "lights": [{"type": "point", "position": [0, 4, 0], "intensity": 16}],
            "materials": {"m": {"ambient": [0, 0, 0]}},
            "surfaces": [
              {"type": "triangle", "vertices": [[-10, 0, -10], [-10, 0, 10], [10, 0, 10]], "material": "m"},
              {"type": "triangle", "vertices": [[-10, 0, -10], [10, 0, 10], [10, 0, -10]], "material": "m"},
              {"type": "sphere", "center": [0.4, 2, 0], "radius": 0.2, "material": "m"}]}"#,
    );
    let img = shade(&w);
    let px = |col: u32| img[(33 * 16 + col) as usize].x;
    assert_eq!(px(30), 0.0, "the shadow");
    assert!(
        px(2) > 0.5,
        "the same distance on the other side is lit: {}",
        px(2)
    );
}

fn scene_err(json: &str) -> String {
    let file = Path::new("bad.json");
    match SceneDesc::parse(json, file) {
        Err(e) => e.to_string(),
        Ok(desc) => match World::build(&desc, file, &|name| {
            Err(format!("{name}: cannot read: no such file"))
        }) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("no error for {json}"),
        },
    }
}

#[test]
fn scene_errors_name_file_line_and_path() {
    let cam = r#""camera": {"eye": [0, 0, 5], "target": [0, 0, 0]}"#;
    let cases = [
        (format!("{{{cam}, \"surfaces\": [{{\"type\": \"sphere\", \"center\": [0, 0, 0], \"radius\": \"big\"}}]}}"),
         ["bad.json:1:", "at surfaces[0].radius", "invalid type: string \"big\""]),
        (format!("{{{cam},\n \"colour\": 1}}"), ["bad.json:2:", "unknown field `colour`", "expected one of"]),
        (format!("{{{cam}, \"surfaces\": [{{\"type\": \"cube\"}}]}}"), ["bad.json:1:", "at surfaces[0]", "unknown variant `cube`"]),
        (format!("{{{cam}, \"surfaces\": [{{\"type\": \"sphere\", \"center\": [0, 0, 0], \"radius\": 1, \"material\": \"gold\"}}]}}"),
         ["bad.json", "at surfaces[0].material", "unknown material 'gold'"]),
        (format!("{{{cam}, \"surfaces\": [{{\"type\": \"mesh\", \"file\": \"nope.off\"}}]}}"), ["bad.json", "at surfaces[0].file", "nope.off: cannot read"]),
        (format!("{{{cam}, \"accel\": \"octree\"}}"), ["bad.json", "at accel", "unknown structure 'octree'"]),
        (format!("{{{cam}, \"spatial_splits\": -1}}"), ["bad.json", "at spatial_splits", "not a fraction"]),
        (format!("{{{cam}, \"image\": {{\"spp\": 0}}}}"), ["bad.json", "at image.spp", "samples per pixel"]),
        (format!("{{{cam}, \"image\": {{\"width\": 32768, \"height\": 32768}}}}"), ["bad.json", "at image", "134,217,728 pixels"]),
        (r#"{"camera": {"eye": [0, 0, 0], "target": [0, 0, 0]}}"#.to_string(), ["bad.json", "at camera:", "the eye is the target"]),
        (r#"{"camera": {"eye": [0.4, 2.2, 7.5], "target": [0, 0, 0], "up": [0.4, 2.2, 7.5]}}"#.to_string(),
         ["bad.json", "at camera:", "up lies along the view"]),
        (r#"{"camera": {"eye": [0, 0, 5], "target": [0, 0, 0], "up": [0, 0, -1e-30]}}"#.to_string(),
         ["bad.json", "at camera:", "up lies along the view"]),
        (r#"{"camera": {"eye": [0, 0, 5], "target": [0, 0, 0], "up": [0, 0, 0]}}"#.to_string(),
         ["bad.json", "at camera.up:", "up is zero"]),
        (r#"{"camera": {"eye": [0, 0, 5], "target": [0, 0, 0], "up": [1e39, 1, 0]}}"#.to_string(),
         ["bad.json", "at camera.up[0]", "past f32's range"]),
        (r#"{"camera": {"eye": [0, 0, 5], "target": [0, 0, 0], "fov": 180}}"#.to_string(),
         ["bad.json", "at camera.fov:", "fov 180 is not within (0, 180) degrees"]),
        ("{\"camera\": {\"eye\": [0, 0, 5], \"target\": [0, 0, 0]},\n\n \"lights\": [{\"type\": \"point\"}]}".to_string(),
         ["bad.json:3:", "at lights[0]", "missing field `position`"]),
        ("{ \"camera\": ".to_string(), ["bad.json:1:", "EOF", ""]),
        (format!("{{{cam}, \"lights\": [{{\"type\": \"point\", \"position\": [0, 0, 1], \"intensity\": -1}}]}}"),
         ["bad.json", "at lights[0].intensity", "at least 0, got -1"]),
        (format!("{{{cam}, \"lights\": [{{\"type\": \"point\", \"position\": [0, 1e39, 1]}}]}}"),
         ["bad.json", "at lights[0].position[1]", "past f32's range"]),
        (format!("{{{cam}, \"lights\": [{{\"type\": \"ambient\", \"color\": [1, -0.5, 1]}}]}}"),
         ["bad.json", "at lights[0].color[1]", "got -0.5"]),
        (format!("{{{cam}, \"lights\": [{{\"type\": \"directional\", \"direction\": [0, -1, 0], \"intensity\": 1e40}}]}}"),
         ["bad.json", "at lights[0].intensity", "got inf"]),
        (format!("{{{cam}, \"materials\": {{\"m\": {{\"diffuse\": [0.5, 0.5, -1]}}}}}}"),
         ["bad.json", "at materials.m.diffuse[2]", "got -1"]),
        (format!("{{{cam}, \"materials\": {{\"m\": {{\"shininess\": -3}}}}}}"),
         ["bad.json", "at materials.m.shininess", "got -3"]),
        (format!("{{{cam}, \"materials\": {{\"m\": {{\"mirror\": -0.5}}}}}}"),
         ["bad.json", "at materials.m.mirror:", "got -0.5"]),
        (format!("{{{cam}, \"image\": {{\"background\": [0, 0, -1]}}}}"),
         ["bad.json", "at image.background[2]", "got -1"]),
        (format!("{{{cam}, \"surfaces\": [{{\"type\": \"triangle\", \"vertices\": [[0, 0, 0], [1, 0, 0], [0, 1e39, 0]]}}]}}"),
         ["bad.json", "at surfaces[0].vertices[2][1]", "finite coordinate"]),
        (format!("{{{cam}, \"surfaces\": [{{\"type\": \"sphere\", \"center\": [0, 1e39, 0], \"radius\": 1}}]}}"),
         ["bad.json", "at surfaces[0].center[1]", "finite coordinate"]),
        (r#"{"camera": {"eye": [0, 0, 1e39], "target": [0, 0, 0]}}"#.to_string(),
         ["bad.json", "at camera.eye[2]", "finite coordinate"]),
    ];
    for (json, wants) in cases {
        let msg = scene_err(&json);
        for want in wants {
            assert!(msg.contains(want), "'{msg}' lacks '{want}'");
        }
    }
}

/// A scene file that starts with a UTF-8 byte-order mark (as some Windows
/// editors save text) parses as the file without it, and its errors keep
/// their lines and columns (those an editor shows, which hides the mark).
#[test]
fn scenes_with_a_byte_order_mark_parse() {
    let json = r#"{"camera": {"eye": [0, 0, 5], "target": [0, 0, 0]}}"#;
    let file = Path::new("bom.json");
    let plain = SceneDesc::parse(json, file).unwrap_or_else(|e| panic!("{e}"));
    let marked = SceneDesc::parse(&format!("\u{feff}{json}"), file);
    assert_eq!(
        format!("{:?}", marked.unwrap_or_else(|e| panic!("{e}"))),
        format!("{plain:?}")
    );
    let bad = "{\"camera\": {}}";
    assert_eq!(scene_err(&format!("\u{feff}{bad}")), scene_err(bad));
    let msg = scene_err(bad);
    assert!(
        msg.contains("bad.json:1:13") && msg.contains("missing field `eye`"),
        "{msg}"
    );
}

/// Radiance errors of a tessellated unit sphere under a directional light
/// (Lambert, no ambient), against the exact sphere's `kd · I · cos θ` at
/// each hit, over the lit pixels of an orthographic view: the largest
/// error, with smooth and with flat shading.
fn sphere_shading_errors() -> (f32, f32) {
    let errors = |shading: &str| {
        let desc = SceneDesc::parse(
            &format!(
                r#"{{"camera": {{"eye": [0, 0, 5], "target": [0, 0, 0]}},
                    "lights": [{{"type": "directional", "direction": [-1, -1, -2]}}],
                    "materials": {{"m": {{"ambient": [0, 0, 0], "diffuse": [1, 1, 1]}}}},
                    "surfaces": [{{"type": "mesh", "file": "sphere", "material": "m", "shading": "{shading}"}}]}}"#
            ),
            Path::new("test.json"),
        )
        .unwrap();
        let w = World::build(&desc, Path::new("test.json"), &|_| {
            Ok(raymesh_mesh::synthetic::uv_sphere(4000, Vec3::ZERO, 1.0).into_indexed())
        })
        .unwrap();
        let to_light = -Vec3::new(-1.0, -1.0, -2.0).normalize();
        let mut worst = 0.0f32;
        for i in 0..60 {
            for j in 0..60 {
                let (x, y) = (i as f32 / 30.0 - 1.0, j as f32 / 30.0 - 1.0);
                let ray =
                    raymesh_accel::Ray::new(Vec3::new(x, y, 5.0), -Vec3::Z, 0.0, f32::INFINITY);
                let Some(hit) = w.surface().intersect(&ray) else {
                    continue;
                };
                let cos = ray.at(hit.t).normalize().dot(to_light);
                // Away from the terminator, where the facets' own shadows fall.
                if cos > 0.3 {
                    let got = w.trace(&ray, 0, &mut 0).x;
                    worst = worst.max((got - cos).abs());
                }
            }
        }
        worst
    };
    (errors("smooth"), errors("flat"))
}

#[test]
fn smooth_shading_follows_the_surface_it_approximates() {
    let (smooth, flat) = sphere_shading_errors();
    // Facets about 4.5° wide: flat shading is off by a few hundredths;
    // interpolated vertex normals (stored in 32 bits each) by far less.
    assert!(flat > 0.02, "flat shading error {flat}");
    assert!(smooth < 0.005, "smooth shading error {smooth}");
}

#[test]
fn only_smooth_meshes_keep_shading_normals() {
    let scene = |shadings: &[&str]| {
        let surfaces: Vec<String> = shadings
            .iter()
            .map(|s| format!(r#"{{"type": "mesh", "file": "cube_quad.off", "shading": "{s}"}}"#))
            .collect();
        world(&format!(
            r#"{{"camera": {{"eye": [0, 0, 5], "target": [0, 0, 0]}},
                "lights": [{{"type": "ambient"}}],
                "surfaces": [{}]}}"#,
            surfaces.join(",")
        ))
        .bytes()
    };
    // cube_quad.off: 6 quads, 12 triangles once fan-triangulated.
    let flat = scene(&["flat"]);
    assert_eq!((flat.triangles, flat.shading), (12, 0));
    assert!(flat.structure > 0);
    let smooth = scene(&["smooth"]);
    assert_eq!((smooth.triangles, smooth.shading), (12, 12 * 12));
    // One file placed twice, flat and smooth: one mesh and one bottom
    // structure, normals kept once; the second placement adds only to the
    // top level (a few bytes).
    let both = scene(&["flat", "smooth"]);
    assert_eq!((both.triangles, both.shading), (12, 12 * 12));
    assert!(both.structure >= smooth.structure);
    assert!(
        both.structure - smooth.structure < 64,
        "{both:?} {smooth:?}"
    );
}
