//! The benchmark's bar chart: Mrays/s per engine for each workload and
//! query, one panel per mesh and thread count, on a log scale (the engines
//! span two orders of magnitude). Drawn as SVG with plotters and
//! rasterized to PNG with resvg, using the system's fonts for the labels.

use crate::Trace;
use anyhow::{bail, Context, Result};
use std::path::Path;

/// Checks the chart's file name, and that it can be written there
/// ([`raymesh::check_writable`]), before the run, not after it.
pub fn check_path(path: &Path) -> Result<()> {
    match path.extension().and_then(|e| e.to_str()) {
        Some("png" | "svg") => raymesh::check_writable(path),
        _ => bail!("{}: the chart is a .png or .svg file", path.display()),
    }
}

/// Draws the chart of `traces` for `engines` (in that order) to `path`.
pub fn draw(path: &Path, engines: &[&str], traces: &[Trace]) -> Result<()> {
    let svg = svg(engines, traces).map_err(|e| anyhow::anyhow!("drawing the chart: {e}"))?;
    if path.extension().and_then(|e| e.to_str()) == Some("svg") {
        return std::fs::write(path, svg).with_context(|| format!("writing {}", path.display()));
    }
    let png = rasterize(&svg)?;
    std::fs::write(path, png).with_context(|| format!("writing {}", path.display()))
}

/// The SVG text of the chart.
fn svg(engines: &[&str], traces: &[Trace]) -> Result<String, Box<dyn std::error::Error>> {
    use plotters::prelude::*;
    // Panels (mesh, threads) and bar groups (workload, query), in run order.
    let mut panels: Vec<(&str, usize)> = Vec::new();
    let mut groups: Vec<(&str, &str)> = Vec::new();
    for t in traces {
        if !panels.contains(&(t.mesh.as_str(), t.threads)) {
            panels.push((t.mesh.as_str(), t.threads));
        }
        if !groups.contains(&(t.workload.as_str(), t.query)) {
            groups.push((t.workload.as_str(), t.query));
        }
    }
    let rates = traces.iter().map(|t| t.mrays_per_s).filter(|r| *r > 0.0);
    let (lo, hi) = rates.fold((f64::INFINITY, 0.0f64), |(a, b), r| (a.min(r), b.max(r)));
    if groups.is_empty() || !(hi > 0.0) {
        return Err("no measurements to draw".into());
    }
    let (lo, hi) = (lo / 2.0, hi * 2.0);
    let mut out = String::new();
    {
        let width = (140 * groups.len() as u32).max(700) + 120;
        let height = 420 * panels.len() as u32;
        let root = SVGBackend::with_string(&mut out, (width, height)).into_drawing_area();
        root.fill(&WHITE)?;
        let areas = root.split_evenly((panels.len(), 1));
        for (panel, &(mesh, t)) in areas.iter().zip(&panels) {
            let title = format!("{mesh}: Mrays/s on {t} thread(s), log scale (higher is better)");
            let mut chart = ChartBuilder::on(panel)
                .caption(title, ("sans-serif", 22))
                .margin(16)
                .x_label_area_size(40)
                .y_label_area_size(60)
                .build_cartesian_2d(0f64..groups.len() as f64, (lo..hi).log_scale())?;
            let label = |x: &f64| {
                let i = x.floor() as usize;
                groups
                    .get(i)
                    .filter(|_| (x - i as f64 - 0.5).abs() < 1e-6)
                    .map_or(String::new(), |(w, q)| format!("{w} {q}"))
            };
            chart
                .configure_mesh()
                .disable_x_mesh()
                .x_labels(2 * groups.len() + 1)
                .x_label_formatter(&label)
                .y_desc("Mrays/s")
                .y_label_formatter(&|y| raymesh::rate(*y))
                .draw()?;
            let n = engines.len() as f64;
            for (k, engine) in engines.iter().enumerate() {
                let color = Palette99::pick(k).to_rgba();
                let bars = groups.iter().enumerate().filter_map(|(g, (w, q))| {
                    let tr = traces.iter().find(|tr| {
                        tr.threads == t
                            && tr.engine == *engine
                            && tr.mesh == mesh
                            && tr.workload == *w
                            && tr.query == *q
                    })?;
                    let x0 = g as f64 + 0.1 + 0.8 * k as f64 / n;
                    let x1 = x0 + 0.8 / n;
                    Some(Rectangle::new(
                        [(x0, lo), (x1, tr.mrays_per_s.max(lo))],
                        color.filled(),
                    ))
                });
                chart
                    .draw_series(bars)?
                    .label(*engine)
                    .legend(move |(x, y)| {
                        Rectangle::new([(x, y - 5), (x + 14, y + 5)], color.filled())
                    });
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .draw()?;
        }
        root.present()?;
    }
    Ok(out)
}

/// PNG bytes of an SVG text, with the system's fonts (the first sans-serif
/// face found stands for `sans-serif`; without any font the labels are
/// left out, and a warning says so).
fn rasterize(svg: &str) -> Result<Vec<u8>> {
    use resvg::{tiny_skia, usvg};
    let mut options = usvg::Options::default();
    let db = options.fontdb_mut();
    db.load_system_fonts();
    let family = [
        "DejaVu Sans",
        "Liberation Sans",
        "Noto Sans",
        "FreeSans",
        "Arial",
    ]
    .into_iter()
    .find(|f| {
        db.faces()
            .any(|face| face.families.iter().any(|(name, _)| name == f))
    })
    .map(str::to_string)
    .or_else(|| {
        db.faces()
            .next()
            .and_then(|f| f.families.first())
            .map(|(n, _)| n.clone())
    });
    match family {
        Some(f) => db.set_sans_serif_family(f),
        None => eprintln!(
            "warning: no fonts found; the chart has no labels (apt-get install -y fonts-dejavu-core)"
        ),
    }
    let tree = usvg::Tree::from_str(svg, &options).context("reading the chart's SVG")?;
    let size = tree.size().to_int_size();
    let mut pixmap = tiny_skia::Pixmap::new(size.width(), size.height()).context("chart size")?;
    resvg::render(&tree, tiny_skia::Transform::default(), &mut pixmap.as_mut());
    pixmap.encode_png().context("encoding the chart as PNG")
}
