//! The options of each `stereoscope` command, one `clap::Args` struct per subcommand (the
//! services' own are in their crates' `cli` modules).

use std::path::PathBuf;
use stereoscope_vision::{Connectivity, ThresholdMethod};

use std::process::ExitCode;
use stereoscope::blobs::{self, BlobsOptions};

use crate::{finish, parse_connectivity, parse_threshold};

mod calibration;
pub use calibration::*;

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
