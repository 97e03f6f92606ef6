//! The options of each `stereoscope` command, one `clap::Args` struct per subcommand (the
//! services' own are in their crates' `cli` modules).

use std::path::PathBuf;
use stereoscope_geometry::calibrate::DistortionModel;
use stereoscope_vision::{Connectivity, ThresholdMethod};

use std::process::ExitCode;
use stereoscope::blobs::{self, BlobsOptions};
use stereoscope::calibrate::{self, CalibrateOptions, Source};

use crate::{finish, parse_connectivity, parse_distortion, parse_size, parse_threshold};

/// `stereoscope blobs`: its options.
#[derive(clap::Args, Debug)]
pub struct BlobsArgs {
    /// Image files.
    #[arg(required = true)]
    pub images: Vec<PathBuf>,
    /// Foreground is pixel >= threshold: a number, `auto` (halfway from the histogram's background knee to the targets), `triangle` or `otsu`.
    #[arg(long, default_value = "auto", value_parser = parse_threshold)]
    pub threshold: ThresholdMethod,
    /// Pixel aspect ratio, pixel width / pixel height (the thesis's cameras: 0.86).
    #[arg(long, default_value_t = 1.0)]
    pub par: f64,
    /// 4 or 8.
    #[arg(long, default_value = "8", value_parser = parse_connectivity)]
    pub connectivity: Connectivity,
    /// Smallest blob reported, pixels.
    #[arg(long, default_value_t = 1)]
    pub min_area: u64,
    /// One JSON object per image per line instead of a table (docs/protocol.md).
    #[arg(long)]
    pub json: bool,
}

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

/// `stereoscope fit-depth`: its options.
#[derive(clap::Args, Debug)]
pub struct FitDepthArgs {
    /// CSV with the header area_px,distance.
    #[arg(long)]
    pub samples: PathBuf,
    /// One JSON object per model per line.
    #[arg(long)]
    pub json: bool,
}

/// `stereoscope reproduce`: its options.
#[derive(clap::Args, Debug)]
pub struct ReproduceArgs {
    /// Folder for the tables, plots and summary (replaced as a whole).
    #[arg(long, default_value = "reproduce")]
    pub out: PathBuf,
    #[arg(long, default_value_t = 1994)]
    pub seed: u64,
    /// Readings per height (the thesis took 25).
    #[arg(long, default_value_t = 25)]
    pub readings: usize,
    /// Gaussian noise, grey levels.
    #[arg(long, default_value_t = 2.0)]
    pub noise: f64,
    /// Skip the table of results at other noise levels (five more runs).
    #[arg(long)]
    pub no_noise_table: bool,
    /// Another lab: a rig file whose first two cameras look down at the floor.
    #[arg(long)]
    pub rig: Option<PathBuf>,
}

/// `stereoscope demo`: its options.
#[derive(clap::Args, Debug)]
pub struct DemoArgs {
    /// How long to measure, seconds from the first pose.
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Run this rig file instead of the built-in one (synthetic cameras, no [[host]]).
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// No live table, only the summary.
    #[arg(long)]
    pub quiet: bool,
    /// The summary as one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Also serve the live view in a browser (docs/viewer.md); the URL is printed.
    #[arg(long)]
    pub view: bool,
    /// Where the live view is served, with --view.
    #[arg(long, default_value = "127.0.0.1:8750")]
    pub view_listen: std::net::SocketAddr,
}

/// `stereoscope grab`: its options.
#[derive(clap::Args, Debug)]
pub struct GrabArgs {
    /// The rig file.
    pub rig: PathBuf,
    /// The camera (its source as the rig describes it: V4L2, Y4M, images, synthetic).
    #[arg(long)]
    pub camera: String,
    /// Frames to save.
    #[arg(long, default_value_t = 1)]
    pub count: u32,
    /// Seconds between saved frames.
    #[arg(long, default_value_t = 1.0)]
    pub every: f64,
    /// pgm (8- or 16-bit, as the camera gives) or png.
    #[arg(long, value_enum, default_value = "pgm")]
    pub format: stereoscope::grab::GrabFormat,
    /// The folder to save into (made if missing).
    pub out: PathBuf,
}

impl GrabArgs {
    pub fn run(self) -> ExitCode {
        let opts = stereoscope::grab::GrabOptions {
            rig: self.rig,
            camera: self.camera,
            count: self.count,
            every_s: self.every,
            format: self.format,
            out: self.out,
        };
        finish(stereoscope::grab::run(&opts, &mut std::io::stdout().lock()))
    }
}

/// `stereoscope process`: a rig's recorded video fused offline.
#[derive(clap::Args, Debug)]
pub struct ProcessArgs {
    /// The rig file (its cameras' sources: Y4M files, image folders or the synthetic scene).
    pub rig: PathBuf,
    /// The session folder to write (session.json, poses.jsonl, observations.jsonl).
    #[arg(long)]
    pub out: PathBuf,
    /// Stop after this many frames of each camera.
    #[arg(long)]
    pub frames: Option<u64>,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

impl ProcessArgs {
    pub fn run(self) -> ExitCode {
        let opts = stereoscope::process::ProcessOptions {
            rig: self.rig,
            out: self.out,
            max_frames: self.frames,
        };
        finish(stereoscope::process::run(
            &opts,
            self.json,
            &mut std::io::stdout().lock(),
            &mut std::io::stderr().lock(),
        ))
    }
}

/// `stereoscope view`: the live view of a running rig.
#[derive(clap::Args, Debug)]
pub struct ViewArgs {
    /// The rig file.
    pub rig: PathBuf,
    #[command(flatten)]
    pub place: stereoscope_service::HostArgs,
    /// Serve on this address and port instead of the rig's `[viewer] listen` (default
    /// 127.0.0.1:8750; port 0 takes a free one, printed at start).
    #[arg(long)]
    pub listen: Option<std::net::SocketAddr>,
    /// A Zenoh router to connect to (default: this host's, from the rig).
    #[arg(long)]
    pub connect: Vec<String>,
    #[command(flatten)]
    pub tls: stereoscope_service::context::TlsArgs,
}

impl ViewArgs {
    /// The viewer service's own arguments.
    pub fn into_service_args(self) -> stereoscope_viewer::cli::Args {
        stereoscope_viewer::cli::Args {
            common: stereoscope_service::CommonArgs {
                rig: self.rig,
                place: self.place,
                zenoh_mode: (!self.connect.is_empty()).then(|| "client".to_string()),
                zenoh_connect: self.connect,
                zenoh_listen: Vec::new(),
                tls: self.tls,
            },
            listen: self.listen,
        }
    }
}

/// `stereoscope run`: its options.
#[derive(clap::Args, Debug)]
pub struct RunArgs {
    /// The rig file.
    pub rig: PathBuf,
    #[command(flatten)]
    pub place: stereoscope_service::HostArgs,
    /// Do not run a Zenoh router here (one runs already).
    #[arg(long)]
    pub no_router: bool,
}

/// `stereoscope status`: its options.
#[derive(clap::Args, Debug)]
pub struct StatusArgs {
    /// The rig file (its first host's router is asked; else give --connect and --rig-name).
    pub rig: Option<PathBuf>,
    /// A Zenoh router endpoint to ask (default: the rig's, else tcp/127.0.0.1:7447).
    #[arg(long)]
    pub connect: Option<String>,
    /// The rig's name, without a rig file.
    #[arg(long)]
    pub rig_name: Option<String>,
    /// Refresh every second until Ctrl-C.
    #[arg(long)]
    pub watch: bool,
    /// One JSON object.
    #[arg(long)]
    pub json: bool,
    /// Flag a camera with no processed frame for this long, milliseconds.
    #[arg(long, default_value_t = 2000)]
    pub stall_ms: u64,
    /// Certificates for a tls/ router (from another PC).
    #[command(flatten)]
    pub tls: stereoscope_service::context::TlsArgs,
}

/// `stereoscope body define`: its options.
#[derive(clap::Args, Debug)]
pub struct BodyDefineArgs {
    /// The new body's name.
    pub name: String,
    /// The rig file (its first host's router is asked unless --connect).
    #[arg(long)]
    pub rig: PathBuf,
    /// A Zenoh router endpoint to ask instead.
    #[arg(long)]
    pub connect: Option<String>,
    /// How long to average, seconds.
    #[arg(long, default_value_t = 1.0)]
    pub seconds: f64,
    /// Define it from a recording instead of live: the markers that moved together in the
    /// session folder (or --objects), their shape averaged over it.
    #[arg(long)]
    pub session: Option<PathBuf>,
    /// Tolerance of a measured inter-marker distance, rig file unit (default 3 mm).
    #[arg(long)]
    pub tolerance: Option<f64>,
    /// Append the table to the rig file (after checking the whole file loads).
    #[arg(long)]
    pub write: bool,
    /// Only these objects' markers (their ids, as the live table and `status` show them).
    #[arg(long, value_delimiter = ',')]
    pub objects: Option<Vec<u32>>,
    /// Only markers inside this box: MINX,MINY,MINZ,MAXX,MAXY,MAXZ (world, rig file unit).
    #[arg(long, value_delimiter = ',', num_args = 6)]
    pub inside: Option<Vec<f64>>,
    /// The body's origin: "centroid", "marker:K" (the K-th marker taken, from 0, in object-id
    /// order), "point:X,Y,Z" (world, rig file unit) or "pivot[:SECONDS]" (then listens 10 s, or
    /// SECONDS, while the body is turned about the point: a pointer's tip in a divot).
    #[arg(long, default_value = "centroid")]
    pub origin: stereoscope::body::Origin,
    /// The body's axes: "world" (the world's, now) or "markers:A,B,C" (x from marker A towards
    /// B, y towards C in their plane).
    #[arg(long, default_value = "world")]
    pub axes: stereoscope::body::Axes,
    /// Certificates for a tls/ router (from another PC).
    #[command(flatten)]
    pub tls: stereoscope_service::context::TlsArgs,
}

impl BodyDefineArgs {
    /// The markers and frame asked for.
    pub fn choice(&self) -> stereoscope::body::DefineChoice {
        stereoscope::body::DefineChoice {
            objects: self.objects.clone(),
            inside: self
                .inside
                .as_ref()
                .and_then(|b| <[f64; 6]>::try_from(b.as_slice()).ok()),
            origin: self.origin.clone(),
            axes: self.axes.clone(),
            tolerance: self.tolerance,
        }
    }
}

/// `stereoscope model define`: its options.
#[derive(clap::Args, Debug)]
pub struct ModelDefineArgs {
    /// The model's name (the rig's [[model]] of that name gets the markers with --write).
    pub name: String,
    /// The rig file.
    #[arg(long)]
    pub rig: PathBuf,
    /// The recorded session of the range-of-motion take (every joint moved).
    #[arg(long)]
    pub session: PathBuf,
    /// The skeleton's URDF (otherwise the rig's [[model]] of that name).
    #[arg(long)]
    pub urdf: Option<PathBuf>,
    /// The recorded session of the model standing still at its zero pose (the same cameras,
    /// the model in the same place).
    #[arg(long)]
    pub home: PathBuf,
    /// Markers are on one link when their distance varies less than this (standard deviation,
    /// rig file unit; default 1.5 mm).
    #[arg(long)]
    pub rigid_tolerance: Option<f64>,
    /// Put the markers in the rig file (after checking the whole file loads).
    #[arg(long)]
    pub write: bool,
    /// The report's figures as one JSON object on stdout instead of the table.
    #[arg(long)]
    pub json: bool,
}

impl ModelDefineArgs {
    pub fn into_options(self) -> stereoscope::model::ModelDefineOptions {
        stereoscope::model::ModelDefineOptions {
            name: self.name,
            rig: self.rig,
            session: self.session,
            urdf: self.urdf,
            home: self.home,
            rigid_tolerance: self.rigid_tolerance,
            write: self.write,
        }
    }
}

/// `stereoscope replay`: its options.
#[derive(clap::Args, Debug)]
pub struct ReplayArgs {
    /// The session folder.
    pub session: PathBuf,
    /// Publish the recorded observations on Zenoh through this router endpoint (with
    /// --frames: the replay's own router listens there, for clients).
    #[arg(long)]
    pub publish: Option<String>,
    /// With --publish: as fast as possible instead of at the recorded pace.
    #[arg(long)]
    pub max_speed: bool,
    /// Feed the recorded frames (frames-<camera>.y4m) through capture, moment workers and
    /// fusion at the recorded pace, and compare the poses with the recorded ones.
    #[arg(long, conflicts_with = "max_speed")]
    pub frames: bool,
    /// With --frames: this many times the recorded pace (frames are dropped if a moment
    /// worker cannot keep up).
    #[arg(long, default_value_t = 1.0, requires = "frames")]
    pub speed: f64,
    /// The comparison as one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Re-fuse the recorded observations with this rig instead of the session's own (a new
    /// calibration of the same cameras), writing the pose frames to --out.
    #[arg(long, requires = "out", conflicts_with_all = ["frames", "publish"])]
    pub rig: Option<PathBuf>,
    /// With --rig: where the re-fused pose frames go (JSON lines, as the recorder's
    /// poses.jsonl).
    #[arg(long, requires = "rig")]
    pub out: Option<PathBuf>,
}

/// `stereoscope export`: its options.
#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    /// The session folder.
    pub session: PathBuf,
    /// csv (one row per object per pose frame), bodies-csv (one row per rigid body per pose
    /// frame), models-csv (one row per joint of each kinematic model per pose frame),
    /// markers-csv (one row per frame on one clock, x/y/z and a filled flag per
    /// marker) or c3d (markers per object and per body, for biomechanics and animation tools;
    /// docs/recording.md).
    #[arg(long, value_parser = ["csv", "bodies-csv", "models-csv", "markers-csv", "c3d"])]
    pub format: String,
    /// Output file (standard output if absent; required for c3d). Written whole or not at
    /// all.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// c3d and markers-csv: fill each marker's gaps of at most this many frames between two
    /// sightings (a body's marker from its other markers, a loose one on a spline); filled
    /// samples have a zero residual and no camera bits in C3D, `filled` 1 in markers-csv
    /// (docs/recording.md).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub fill_gaps: Option<u32>,
}

/// `stereoscope triangulate`: its options.
#[derive(clap::Args, Debug)]
pub struct TriangulateArgs {
    /// The rig file (docs/rig.md).
    #[arg(long)]
    pub rig: PathBuf,
    /// CSV with the header point,camera,u,v (camera = a camera id of the rig).
    #[arg(long)]
    pub points: PathBuf,
    /// One JSON object per point per line.
    #[arg(long)]
    pub json: bool,
}

impl BlobsArgs {
    /// Runs the command; the process's exit status.
    pub fn run(self) -> ExitCode {
        let BlobsArgs {
            images,
            threshold,
            par,
            connectivity,
            min_area,
            json,
        } = self;
        let opts = BlobsOptions {
            images,
            threshold,
            par,
            connectivity,
            min_area_px: min_area,
            json,
        };
        let (stdout, stderr) = (std::io::stdout(), std::io::stderr());
        match blobs::run(&opts, &mut stdout.lock(), &mut stderr.lock()) {
            Ok(0) => ExitCode::SUCCESS,
            Ok(_) => ExitCode::from(1),
            Err(e) => {
                eprintln!("error: writing output: {e}");
                ExitCode::from(2)
            }
        }
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

impl ReproduceArgs {
    /// Runs the command; the process's exit status.
    pub fn run(self) -> ExitCode {
        let ReproduceArgs {
            out,
            seed,
            readings,
            noise,
            no_noise_table,
            rig,
        } = self;
        let opts = stereoscope_reproduce::ReproduceOptions {
            seed,
            readings: readings.max(1),
            noise_sigma: noise,
            noise_sweep: !no_noise_table,
            rig,
            progress: true,
            ..stereoscope_reproduce::ReproduceOptions::realistic(out)
        };
        let result = stereoscope_reproduce::run(&opts).and_then(|r| {
            stereoscope_reproduce::write(&r, &opts)?;
            print!("{}", stereoscope_reproduce::summary_md(&r, &opts));
            println!("\nTables and plots in {}", opts.out.display());
            Ok(0)
        });
        finish(result)
    }
}
