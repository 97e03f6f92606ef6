//! `stereoscope target dot-grid`: the dot-grid calibration target (`stereoscope_geometry::
//! dotgrid`) as a page to print at true size, SVG or PDF: white dots on a black board, the
//! larger origin dot, the grid's x and y axes drawn and named on the board, and below it the
//! layout, the dot size, a 100 mm bar to check the print's scale, and how near a camera must
//! be (`docs/calibration.md`, step 1).

use anyhow::{Context, bail};
use std::fmt::Write as _;
use std::io::Write;
use std::path::PathBuf;
use stereoscope_geometry::dotgrid::DotGrid;
use stereoscope_rig::Units;

#[derive(Debug, Clone)]
pub struct TargetOptions {
    pub cols: usize,
    pub rows: usize,
    /// In `units`; the largest whole millimetre that fits `paper` when absent.
    pub spacing: Option<f64>,
    pub paper: Paper,
    pub units: Units,
    /// `.svg` or `.pdf`.
    pub out: PathBuf,
}

/// The page's layout in millimetres, y down from the page's top-left corner.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Page {
    pub width_mm: f64,
    pub height_mm: f64,
    /// The board's top-left corner and size.
    pub board: [f64; 4],
    /// The origin dot's centre.
    pub origin: [f64; 2],
    pub spacing_mm: f64,
    pub dot_radius_mm: f64,
    pub origin_radius_mm: f64,
}

/// A dot image narrower than this many pixels loses its centroid's precision.
const MIN_DOT_PX: f64 = 8.0;
/// The band below the board for the text and the scale bar, mm.
const TEXT_BAND_MM: f64 = 28.0;

pub fn page(grid: &DotGrid, unit_mm: f64) -> Page {
    let s = grid.spacing * unit_mm;
    let margin = s;
    let bw = (grid.cols - 1) as f64 * s + 2.0 * margin;
    let bh = (grid.rows - 1) as f64 * s + 2.0 * margin;
    let edge = 10.0;
    Page {
        width_mm: bw + 2.0 * edge,
        height_mm: bh + 2.0 * edge + TEXT_BAND_MM,
        board: [edge, edge, bw, bh],
        origin: [edge + margin, edge + margin],
        spacing_mm: s,
        dot_radius_mm: grid.dot_radius * unit_mm,
        origin_radius_mm: grid.dot_radius * grid.origin_scale * unit_mm,
    }
}

/// The lines of text under the board.
fn legend(grid: &DotGrid, p: &Page) -> [String; 3] {
    let d = 2.0 * p.dot_radius_mm;
    [
        format!(
            "Stereoscope dot grid {} x {}: {} columns along x, {} rows along y, {:.1} mm apart; big dot = origin.",
            grid.cols, grid.rows, grid.cols, grid.rows, p.spacing_mm
        ),
        format!(
            "Dots {d:.1} mm across (origin {:.1} mm). Print at 100 % (no fit to page); the bar must measure 100 mm.",
            2.0 * p.origin_radius_mm
        ),
        format!(
            "For dot images {MIN_DOT_PX:.0} px across, keep the camera within {:.2} m at f = 600 px, {:.2} m at f = 1000 px (f x dot / {MIN_DOT_PX:.0}).",
            0.6 * d / MIN_DOT_PX,
            d / MIN_DOT_PX
        ),
    ]
}

/// Arrow segments of the axes on the board, outside the dots: x along the top margin from the
/// origin dot, y along the left margin; and where their labels go.
/// A line on the page, mm: from (x0, y0) to (x1, y1).
type Segment = [f64; 4];
/// A label on the page, mm: where, and what.
type Label = (f64, f64, &'static str);

fn axes(p: &Page) -> ([Segment; 6], [Label; 2]) {
    let [ox, oy] = p.origin;
    let s = p.spacing_mm;
    let (len, head) = (s * 1.5, s * 0.15);
    let (ay, ax) = (oy - s * 0.6, ox - s * 0.6);
    (
        [
            [ox, ay, ox + len, ay],
            [ox + len, ay, ox + len - head, ay - head * 0.6],
            [ox + len, ay, ox + len - head, ay + head * 0.6],
            [ax, oy, ax, oy + len],
            [ax, oy + len, ax - head * 0.6, oy + len - head],
            [ax, oy + len, ax + head * 0.6, oy + len - head],
        ],
        [
            (ox + len + head, ay + head * 0.5, "x"),
            (ax - head * 0.5, oy + len + head * 2.0, "y"),
        ],
    )
}

fn dots(grid: &DotGrid, p: &Page) -> Vec<(f64, f64, f64)> {
    (0..grid.len())
        .map(|i| {
            let q = grid.point(i);
            let r = if i == 0 {
                p.origin_radius_mm
            } else {
                p.dot_radius_mm
            };
            (
                p.origin[0] + q.x / grid.spacing * p.spacing_mm,
                p.origin[1] + q.y / grid.spacing * p.spacing_mm,
                r,
            )
        })
        .collect()
}

/// The page as SVG, sized in millimetres.
pub fn svg(grid: &DotGrid, unit_mm: f64) -> String {
    let p = page(grid, unit_mm);
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}mm\" height=\"{h}mm\" viewBox=\"0 0 {w} {h}\">\n<rect x=\"0\" y=\"0\" width=\"{w}\" height=\"{h}\" fill=\"#ffffff\"/>\n<rect x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" fill=\"#000000\"/>\n",
        p.board[0],
        p.board[1],
        p.board[2],
        p.board[3],
        w = p.width_mm,
        h = p.height_mm
    );
    for (x, y, r) in dots(grid, &p) {
        let _ = writeln!(
            s,
            "<circle cx=\"{x:.4}\" cy=\"{y:.4}\" r=\"{r:.4}\" fill=\"#ffffff\"/>"
        );
    }
    let (lines, labels) = axes(&p);
    let stroke = p.spacing_mm * 0.04;
    for [x0, y0, x1, y1] in lines {
        let _ = writeln!(
            s,
            "<line x1=\"{x0:.4}\" y1=\"{y0:.4}\" x2=\"{x1:.4}\" y2=\"{y1:.4}\" stroke=\"#404040\" stroke-width=\"{stroke:.4}\"/>"
        );
    }
    for (x, y, t) in labels {
        let _ = writeln!(
            s,
            "<text x=\"{x:.4}\" y=\"{y:.4}\" font-family=\"Helvetica, Arial, sans-serif\" font-size=\"{:.4}\" fill=\"#404040\">{t}</text>",
            p.spacing_mm * 0.35
        );
    }
    let top = p.board[1] + p.board[3];
    for (k, line) in legend(grid, &p).iter().enumerate() {
        let _ = writeln!(
            s,
            "<text x=\"{:.4}\" y=\"{:.4}\" font-family=\"Helvetica, Arial, sans-serif\" font-size=\"3\" fill=\"#000000\">{line}</text>",
            p.board[0],
            top + 6.0 + 4.5 * k as f64
        );
    }
    let _ = writeln!(
        s,
        "<rect x=\"{:.4}\" y=\"{:.4}\" width=\"100\" height=\"2\" fill=\"#000000\"/>\n</svg>",
        p.board[0],
        top + 20.0
    );
    s
}

/// A PDF string literal's text: ASCII, with `\`, `(` and `)` escaped.
fn pdf_text(t: &str) -> String {
    t.chars()
        .map(|c| match c {
            '\\' | '(' | ')' => format!("\\{c}"),
            c if c.is_ascii() => c.to_string(),
            _ => "?".to_string(),
        })
        .collect()
}

/// The page as a one-page PDF, sized in points (1 mm = 72 / 25.4 pt), vector shapes and the
/// standard Helvetica font.
pub fn pdf(grid: &DotGrid, unit_mm: f64) -> Vec<u8> {
    let p = page(grid, unit_mm);
    let k = 72.0 / 25.4;
    let h_pt = p.height_mm * k;
    // mm, y down → pt, y up.
    let x = |v: f64| v * k;
    let y = |v: f64| h_pt - v * k;
    let mut c = String::new();
    let _ = writeln!(
        c,
        "1 g 0 0 {:.4} {:.4} re f",
        p.width_mm * k,
        p.height_mm * k
    );
    let _ = writeln!(
        c,
        "0 g {:.4} {:.4} {:.4} {:.4} re f",
        x(p.board[0]),
        y(p.board[1] + p.board[3]),
        p.board[2] * k,
        p.board[3] * k
    );
    c.push_str("1 g\n");
    // A circle as four cubic Béziers.
    let kappa = 0.552_284_749_830_793_4;
    for (cx, cy, r) in dots(grid, &p) {
        let (cx, cy, r) = (x(cx), y(cy), r * k);
        let m = r * kappa;
        let _ = writeln!(
            c,
            "{:.4} {cy:.4} m {:.4} {:.4} {:.4} {:.4} {cx:.4} {:.4} c {:.4} {:.4} {:.4} {:.4} {:.4} {cy:.4} c {:.4} {:.4} {:.4} {:.4} {cx:.4} {:.4} c {:.4} {:.4} {:.4} {:.4} {:.4} {cy:.4} c f",
            cx + r,
            cx + r,
            cy + m,
            cx + m,
            cy + r,
            cy + r,
            cx - m,
            cy + r,
            cx - r,
            cy + m,
            cx - r,
            cx - r,
            cy - m,
            cx - m,
            cy - r,
            cy - r,
            cx + m,
            cy - r,
            cx + r,
            cy - m,
            cx + r
        );
    }
    let (lines, labels) = axes(&p);
    let _ = writeln!(c, "0.25 G {:.4} w", p.spacing_mm * 0.04 * k);
    for [x0, y0, x1, y1] in lines {
        let _ = writeln!(
            c,
            "{:.4} {:.4} m {:.4} {:.4} l S",
            x(x0),
            y(y0),
            x(x1),
            y(y1)
        );
    }
    for (lx, ly, t) in labels {
        let _ = writeln!(
            c,
            "0.25 g BT /F1 {:.4} Tf {:.4} {:.4} Td ({}) Tj ET",
            p.spacing_mm * 0.35 * k,
            x(lx),
            y(ly),
            pdf_text(t)
        );
    }
    let top = p.board[1] + p.board[3];
    for (i, line) in legend(grid, &p).iter().enumerate() {
        let _ = writeln!(
            c,
            "0 g BT /F1 {:.4} Tf {:.4} {:.4} Td ({}) Tj ET",
            3.0 * k,
            x(p.board[0]),
            y(top + 6.0 + 4.5 * i as f64),
            pdf_text(line)
        );
    }
    let _ = writeln!(
        c,
        "0 g {:.4} {:.4} {:.4} {:.4} re f",
        x(p.board[0]),
        y(top + 22.0),
        100.0 * k,
        2.0 * k
    );
    let objects = [
        "<< /Type /Catalog /Pages 2 0 R >>".to_string(),
        "<< /Type /Pages /Kids [3 0 R] /Count 1 >>".to_string(),
        format!(
            "<< /Type /Page /Parent 2 0 R /MediaBox [0 0 {:.4} {:.4}] /Contents 4 0 R /Resources << /Font << /F1 5 0 R >> >> >>",
            p.width_mm * k,
            h_pt
        ),
        format!("<< /Length {} >>\nstream\n{c}endstream", c.len()),
        "<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica >>".to_string(),
    ];
    let mut out = String::from("%PDF-1.4\n");
    let mut offsets = Vec::new();
    for (i, o) in objects.iter().enumerate() {
        offsets.push(out.len());
        let _ = write!(out, "{} 0 obj\n{o}\nendobj\n", i + 1);
    }
    let xref = out.len();
    let _ = write!(out, "xref\n0 {}\n0000000000 65535 f \n", objects.len() + 1);
    for o in offsets {
        let _ = writeln!(out, "{o:010} 00000 n ");
    }
    let _ = write!(
        out,
        "trailer\n<< /Size {} /Root 1 0 R >>\nstartxref\n{xref}\n%%EOF\n",
        objects.len() + 1
    );
    out.into_bytes()
}

/// The paper the page must fit, either way round.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Paper {
    /// Both A4 (210 × 297 mm) and US Letter (215.9 × 279.4 mm): 210 × 279.4 mm.
    A4Letter,
    A4,
    Letter,
    /// Any size (a plotter, or a board printed by a shop).
    Any,
}

impl Paper {
    /// Width and height, mm, portrait.
    fn size_mm(self) -> Option<(f64, f64)> {
        match self {
            Paper::A4Letter => Some((210.0, 279.4)),
            Paper::A4 => Some((210.0, 297.0)),
            Paper::Letter => Some((215.9, 279.4)),
            Paper::Any => None,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Paper::A4Letter => "A4 and Letter",
            Paper::A4 => "A4",
            Paper::Letter => "Letter",
            Paper::Any => "any paper",
        }
    }

    /// Whether a page of `w` × `h` mm fits, either way round.
    pub fn fits(self, w: f64, h: f64) -> bool {
        match self.size_mm() {
            None => true,
            Some((pw, ph)) => (w <= pw && h <= ph) || (w <= ph && h <= pw),
        }
    }
}

/// The page's format, named by its file's extension, is not one this writes.
fn not_a_page_format(out: &std::path::Path) -> anyhow::Result<Vec<u8>> {
    bail!("{}: the page is written as .svg or .pdf", out.display())
}

/// The largest whole-millimetre spacing whose page fits `paper` (at least 5 mm).
pub fn largest_spacing_mm(cols: usize, rows: usize, paper: Paper) -> Option<f64> {
    (5..=200).rev().map(f64::from).find(|&s| {
        DotGrid::new(cols, rows, s).is_ok_and(|g| {
            let p = page(&g, 1.0);
            paper.fits(p.width_mm, p.height_mm)
        })
    })
}

/// Runs the command; `Ok(0)` when the page was written.
pub fn run(opts: &TargetOptions, out: &mut impl Write) -> anyhow::Result<usize> {
    let unit_mm = opts.units.metres() * 1000.0;
    let ext = opts
        .out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if !matches!(ext.as_deref(), Some("svg" | "pdf")) {
        not_a_page_format(&opts.out)?;
    }
    let spacing = match opts.spacing {
        Some(s) => s,
        None => {
            if opts.paper == Paper::Any {
                bail!("--page any needs --spacing: no paper size to fit the grid to");
            }
            let mm = largest_spacing_mm(opts.cols, opts.rows, opts.paper).ok_or_else(|| {
                anyhow::anyhow!(
                    "a {}x{} grid does not fit {} even at 5 mm spacing: fewer dots, or --page any with --spacing",
                    opts.cols,
                    opts.rows,
                    opts.paper.name()
                )
            })?;
            mm / unit_mm
        }
    };
    let grid = DotGrid::new(opts.cols, opts.rows, spacing)?;
    let laid = page(&grid, unit_mm);
    if !opts.paper.fits(laid.width_mm, laid.height_mm) {
        let hint = largest_spacing_mm(opts.cols, opts.rows, opts.paper)
            .map(|mm| format!("--spacing {} or less ({mm} mm)", mm / unit_mm))
            .unwrap_or_else(|| "fewer dots".into());
        bail!(
            "a {}x{} grid at spacing {spacing} {} makes a {:.0} × {:.0} mm page, larger than {} either way round: use {hint}, or --page any to print it larger",
            opts.cols,
            opts.rows,
            opts.units,
            laid.width_mm,
            laid.height_mm,
            opts.paper.name()
        );
    }
    let bytes = match ext.as_deref() {
        Some("svg") => svg(&grid, unit_mm).into_bytes(),
        Some("pdf") => pdf(&grid, unit_mm),
        _ => not_a_page_format(&opts.out)?,
    };
    std::fs::write(&opts.out, bytes)
        .with_context(|| format!("{}: cannot write", opts.out.display()))?;
    let p = page(&grid, unit_mm);
    writeln!(
        out,
        "wrote {}: {:.0} x {:.0} mm{}",
        opts.out.display(),
        p.width_mm,
        p.height_mm,
        if opts.paper == Paper::Any {
            String::new()
        } else {
            format!(
                ", fits {}{}",
                opts.paper.name(),
                if p.width_mm > p.height_mm {
                    " (landscape)"
                } else {
                    ""
                }
            )
        }
    )?;
    for line in legend(&grid, &p) {
        writeln!(out, "  {line}")?;
    }
    if opts.cols == opts.rows {
        writeln!(
            out,
            "warning: a square grid ({0} x {0}) tells its x axis from its y axis only in views from the front: different column and row counts are safer",
            opts.cols
        )?;
    }
    writeln!(
        out,
        "  calibrate with: stereoscope calibrate --dot-grid {}x{} --spacing {} --units {} IMAGES...",
        opts.cols, opts.rows, spacing, opts.units
    )?;
    Ok(0)
}
