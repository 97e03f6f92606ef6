//! The options of `stereoscope calibrate` and its steps (mask, floor, wand) and of `stereoscope
//! target dot-grid`, and how `calibrate` runs.

use std::path::PathBuf;
use std::process::ExitCode;
use stereoscope::calibrate::{self, CalibrateOptions, Source};
use stereoscope_geometry::calibrate::DistortionModel;

use crate::{finish, parse_distortion, parse_size};

/// `stereoscope calibrate`: its options.
#[derive(clap::Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub struct CalibrateArgs {
    /// A step of a rig's calibration instead of one camera's intrinsics.
    #[command(subcommand)]
    pub step: Option<CalibrateStep>,
    /// CSV with the header view,X,Y,Z,u,v: target coordinates and pixels, one row per point.
    #[arg(long, conflicts_with = "dot_grid")]
    pub points: Option<PathBuf>,
    /// Image size WxH (needed with --points; read from the images otherwise).
    #[arg(long, value_parser = parse_size)]
    pub image_size: Option<(u32, u32)>,
    /// Calibrate from images of a COLSxROWS dot grid (docs/geometry.md, the dot-grid target).
    #[arg(long, value_parser = parse_size, requires = "spacing")]
    pub dot_grid: Option<(u32, u32)>,
    /// Dot spacing, in --units.
    #[arg(long)]
    pub spacing: Option<f64>,
    /// Images of the dot grid.
    pub images: Vec<PathBuf>,
    /// Unit of target coordinates and of the output translations: m, cm or mm.
    #[arg(long, default_value = "m")]
    pub units: stereoscope_rig::Units,
    /// Distortion terms to estimate: none, radial (k1 k2), tangential (k1 k2 p1 p2, k3 fixed at
    /// 0: OpenCV's CALIB_FIX_K3) or full (k1 k2 p1 p2 k3).
    #[arg(long, default_value = "full", value_parser = parse_distortion)]
    pub distortion: DistortionModel,
    /// Camera id in the written camera table.
    #[arg(long, default_value = "camera")]
    pub id: String,
    /// Also write the camera table (rig file format) to this file.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// One JSON object instead of the report (docs/protocol.md).
    #[arg(long)]
    pub json: bool,
}

/// `stereoscope calibrate STEP`.
#[derive(clap::Subcommand, Debug)]
pub enum CalibrateStep {
    /// Every camera's pose from a wand waved through the volume (docs/calibration.md): the
    /// cameras' intrinsics from the rig, the wand's blobs from a recorder's observations.jsonl
    /// or a CSV frame,camera,u,v.
    Wand(WandArgs),
    /// The world's frame from an L-frame on the floor (corner the origin, long arm +x, short
    /// arm +y, z up), from a recording's poses.jsonl taken while it lay still.
    Floor(FloorArgs),
    /// Masks for what is bright and not a marker (lamps, reflections): watch the running rig
    /// with no markers in view and write a rectangle round each blob into the cameras'
    /// moments.mask; --check shows what the cameras still see.
    Mask(MaskArgs),
}

/// `stereoscope calibrate mask`: its options.
#[derive(clap::Args, Debug)]
pub struct MaskArgs {
    /// The rig file (running: its services are asked).
    #[arg(long)]
    pub rig: PathBuf,
    /// Seconds to watch.
    #[arg(long, default_value_t = 3.0)]
    pub seconds: f64,
    /// Pixels added round each blob's box.
    #[arg(long, default_value_t = 4)]
    pub grow: u32,
    /// Write the rig file with the masks here (may be the rig file itself).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Only say what each camera sees now (exit status 1 if any camera sees something).
    #[arg(long)]
    pub check: bool,
    /// A Zenoh router to ask (default: the rig's first host's).
    #[arg(long)]
    pub connect: Option<String>,
    #[command(flatten)]
    pub tls: stereoscope_service::context::TlsArgs,
}

impl MaskArgs {
    pub fn run(self) -> ExitCode {
        let opts = stereoscope::mask::MaskOptions {
            rig: self.rig,
            connect: self.connect,
            seconds: self.seconds,
            grow_px: self.grow,
            out: self.out,
            check: self.check,
            tls: self.tls,
        };
        finish(stereoscope::mask::run(&opts, &mut std::io::stdout().lock()))
    }
}

/// `stereoscope calibrate floor`: its options.
#[derive(clap::Args, Debug)]
pub struct FloorArgs {
    /// The rig file with its cameras' poses (from `calibrate wand`).
    #[arg(long)]
    pub rig: PathBuf,
    /// A recorder's poses.jsonl taken while the L-frame (or the floor markers) lay still.
    #[arg(long)]
    pub poses: PathBuf,
    /// The L-frame's arms, corner marker to end marker: LONG,SHORT (long is +x, short +y), or
    /// LONG,SHORT,MIDDLE for a fourth marker on the long arm MIDDLE from the corner.
    #[arg(
        long,
        value_delimiter = ',',
        required_unless_present = "points",
        conflicts_with = "points"
    )]
    pub l_frame: Vec<f64>,
    /// Instead of an L-frame: the markers in --poses lie on the floor (3 or more, not in a
    /// line); --origin gives the origin, --x-axis the +x direction.
    #[arg(long, requires = "origin")]
    pub points: bool,
    /// With --points: a poses.jsonl of one marker lying at the origin.
    #[arg(long)]
    pub origin: Option<PathBuf>,
    /// With --points: a poses.jsonl of one marker lying on the +x axis (default: +x is camera
    /// 0's right, laid on the floor).
    #[arg(long, requires = "points")]
    pub x_axis: Option<PathBuf>,
    /// How far the markers' centres are above the floor (their radius, plus the L-frame's
    /// thickness), in --units: z = 0 is put that far below them.
    #[arg(long, default_value_t = 0.0)]
    pub marker_height: f64,
    /// Scale the rig so that the L-frame's markers are their known distances apart: after a
    /// one-marker wand, which gives no scale.
    #[arg(long, conflicts_with = "points")]
    pub scale: bool,
    /// Unit of --l-frame and --marker-height: m, cm or mm.
    #[arg(long, default_value = "mm")]
    pub units: stereoscope_rig::Units,
    /// Write the rig file with the poses in the floor's world here.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print the report as one JSON object.
    #[arg(long)]
    pub json: bool,
}

impl FloorArgs {
    pub fn run(self) -> ExitCode {
        use stereoscope::floor::FloorMethod;
        let method = match (self.points, self.origin, &self.l_frame[..]) {
            (true, Some(origin), _) => FloorMethod::Points {
                origin,
                x_axis: self.x_axis,
            },
            (false, _, &[long, short]) => FloorMethod::LFrame {
                long,
                short,
                middle: None,
            },
            (false, _, &[long, short, middle]) => FloorMethod::LFrame {
                long,
                short,
                middle: Some(middle),
            },
            _ => {
                eprintln!(
                    "error: --l-frame takes LONG,SHORT or LONG,SHORT,MIDDLE (two or three lengths), not {:?}; or give --points with --origin",
                    self.l_frame
                );
                return ExitCode::from(2);
            }
        };
        let opts = stereoscope::floor::FloorOptions {
            rig: self.rig,
            poses: self.poses,
            method,
            marker_height: self.marker_height,
            scale: self.scale,
            units: self.units,
            out: self.out,
            json: self.json,
        };
        finish(stereoscope::floor::run(
            &opts,
            &mut std::io::stdout().lock(),
            &mut std::io::stderr().lock(),
        ))
    }
}

/// `stereoscope calibrate wand`: its options.
#[derive(clap::Args, Debug)]
pub struct WandArgs {
    /// The rig file: each camera's intrinsics and distortion (a pose is not needed).
    #[arg(long)]
    pub rig: PathBuf,
    /// The wand's blobs: a recorder's observations.jsonl, or a .csv with the header
    /// frame,camera,u,v (camera by its rig id, pixels as observed).
    #[arg(long, required_unless_present = "live", conflicts_with = "live")]
    pub observations: Option<PathBuf>,
    /// Collect the wand's blobs from the running rig until every camera's image is covered
    /// (a bar per camera fills; the viewer shows the coverage), then solve.
    #[arg(long)]
    pub live: bool,
    /// Adjust each camera's focal lengths and principal point with the poses (lens distortion
    /// kept), and write them: for intrinsics a few percent off.
    #[arg(long)]
    pub refine_intrinsics: bool,
    /// With --live: the longest collection, seconds.
    #[arg(long, default_value_t = 300.0)]
    pub seconds: f64,
    /// With --live: the share of each camera's image cells (8 × 6) to cover.
    #[arg(long, default_value_t = 0.7)]
    pub coverage: f64,
    /// With --live: the fewest wand samples per camera.
    #[arg(long, default_value_t = 1000)]
    pub min_samples: u64,
    /// With --live: a Zenoh router to ask (default: the rig's first host's).
    #[arg(long)]
    pub connect: Option<String>,
    #[command(flatten)]
    pub tls: stereoscope_service::context::TlsArgs,
    /// The wand: 0 (one marker: no scale, set it later with `calibrate floor --scale`), D (two
    /// markers D apart) or D1,D2 (three in a line, D1 and D2 from one end).
    #[arg(long, value_delimiter = ',', required = true)]
    pub wand: Vec<f64>,
    /// Unit of --wand: m, cm or mm.
    #[arg(long, default_value = "mm")]
    pub units: stereoscope_rig::Units,
    /// Write the rig file with the cameras' poses here (the rest of the file as it was).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write wand-report.md and wand-report.json into this folder.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Print the report as one JSON object instead of Markdown.
    #[arg(long)]
    pub json: bool,
}

impl WandArgs {
    pub fn run(self) -> ExitCode {
        use stereoscope::wand::WandInput;
        use stereoscope::wand_live::LiveWand;
        let input = match self.observations {
            Some(path) => WandInput::File(path),
            None => WandInput::Live(LiveWand {
                connect: self.connect,
                tls: self.tls,
                max_seconds: self.seconds,
                target: self.coverage,
                min_samples: self.min_samples,
            }),
        };
        let opts = stereoscope::wand::WandOptions {
            rig: self.rig,
            input,
            refine_intrinsics: self.refine_intrinsics,
            wand: self.wand,
            units: self.units,
            out: self.out,
            report: self.report,
            json: self.json,
        };
        finish(stereoscope::wand::run(
            &opts,
            &mut std::io::stdout().lock(),
            &mut std::io::stderr().lock(),
        ))
    }
}

/// `stereoscope target dot-grid`: its options.
#[derive(clap::Args, Debug)]
pub struct DotGridTargetArgs {
    /// COLSxROWS: dots along x (the rows run right from the big dot), dots along y.
    #[arg(value_parser = parse_size)]
    pub size: (u32, u32),
    /// Dot spacing, in --units (default: the largest whole millimetre whose page fits --page).
    #[arg(long)]
    pub spacing: Option<f64>,
    /// Unit of --spacing: m, cm or mm.
    #[arg(long, default_value = "mm")]
    pub units: stereoscope_rig::Units,
    /// The paper the page must fit, either way round: a4-letter (both), a4, letter, or any.
    #[arg(long, value_enum, default_value = "a4-letter")]
    pub page: stereoscope::target::Paper,
    /// The page to write: FILE.svg or FILE.pdf.
    #[arg(long)]
    pub out: PathBuf,
}

impl DotGridTargetArgs {
    pub fn run(self) -> ExitCode {
        let opts = stereoscope::target::TargetOptions {
            cols: self.size.0 as usize,
            rows: self.size.1 as usize,
            spacing: self.spacing,
            paper: self.page,
            units: self.units,
            out: self.out,
        };
        finish(stereoscope::target::run(
            &opts,
            &mut std::io::stdout().lock(),
        ))
    }
}

impl CalibrateArgs {
    /// Runs the command; the process's exit status.
    pub fn run(self) -> ExitCode {
        let CalibrateArgs {
            step,
            points,
            image_size,
            dot_grid,
            spacing,
            images,
            units,
            distortion,
            id,
            out,
            json,
        } = self;
        match step {
            Some(CalibrateStep::Wand(w)) => return w.run(),
            Some(CalibrateStep::Floor(f)) => return f.run(),
            Some(CalibrateStep::Mask(m)) => return m.run(),
            None => {}
        }
        let source = match (points, dot_grid, spacing) {
            (Some(p), None, _) if images.is_empty() => Source::Points(p),
            (Some(_), None, _) => {
                eprintln!(
                    "error: images are only read with --dot-grid (got --points and {} image(s))",
                    images.len()
                );
                return ExitCode::from(2);
            }
            (None, Some((cols, rows)), Some(spacing)) if !images.is_empty() => Source::DotGrid {
                images,
                cols: cols as usize,
                rows: rows as usize,
                spacing,
            },
            (None, Some(_), _) => {
                eprintln!("error: --dot-grid needs --spacing and at least one image");
                return ExitCode::from(2);
            }
            _ => {
                eprintln!(
                    "error: give --points FILE.csv, or --dot-grid COLSxROWS --spacing S IMAGE..."
                );
                return ExitCode::from(2);
            }
        };
        let opts = CalibrateOptions {
            source,
            image_size,
            units,
            distortion,
            id,
            json,
            out,
        };
        finish(calibrate::run(
            &opts,
            &mut std::io::stdout().lock(),
            &mut std::io::stderr().lock(),
        ))
    }
}
