//! `stereoscope`: the command line. Parses arguments and calls the library.

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use stereoscope::blobs::{self, BlobsOptions};
use stereoscope::calibrate::{self, CalibrateOptions, Source};
use stereoscope::fitdepth::{self, FitDepthOptions};
use stereoscope::triangulate::{self, TriangulateOptions};
use stereoscope_geometry::calibrate::DistortionModel;
use stereoscope_vision::{Connectivity, ThresholdMethod};

#[derive(Parser, Debug)]
#[command(
    name = "stereoscope",
    version,
    about = "Recover the 3D position and heading of bright targets from cameras."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Find every bright blob in images (PGM P2/P5 8/16-bit, PNG) and print its moments.
    Blobs {
        /// Image files.
        #[arg(required = true)]
        images: Vec<PathBuf>,
        /// Foreground is pixel >= threshold: a number, `auto` (halfway from the histogram's background knee to the targets), `triangle` or `otsu`.
        #[arg(long, default_value = "auto", value_parser = parse_threshold)]
        threshold: ThresholdMethod,
        /// Pixel aspect ratio, pixel width / pixel height (the thesis's cameras: 0.86).
        #[arg(long, default_value_t = 1.0)]
        par: f64,
        /// 4 or 8.
        #[arg(long, default_value = "8", value_parser = parse_connectivity)]
        connectivity: Connectivity,
        /// Smallest blob reported, pixels.
        #[arg(long, default_value_t = 1)]
        min_area: u64,
        /// One JSON object per image per line instead of a table (docs/protocol.md).
        #[arg(long)]
        json: bool,
    },
    /// Calibrate a camera from target points (CSV view,X,Y,Z,u,v) or from dot-grid images.
    Calibrate {
        /// CSV with the header view,X,Y,Z,u,v: target coordinates and pixels, one row per point.
        #[arg(long, conflicts_with = "dot_grid")]
        points: Option<PathBuf>,
        /// Image size WxH (needed with --points; read from the images otherwise).
        #[arg(long, value_parser = parse_size)]
        image_size: Option<(u32, u32)>,
        /// Calibrate from images of a COLSxROWS dot grid (docs/geometry.md, the dot-grid target).
        #[arg(long, value_parser = parse_size, requires = "spacing")]
        dot_grid: Option<(u32, u32)>,
        /// Dot spacing, in --units.
        #[arg(long)]
        spacing: Option<f64>,
        /// Images of the dot grid.
        images: Vec<PathBuf>,
        /// Unit of target coordinates and of the output translations: m, cm or mm.
        #[arg(long, default_value = "m")]
        units: stereoscope_rig::Units,
        /// Distortion terms to estimate: none, radial (k1 k2) or full (k1 k2 p1 p2 k3).
        #[arg(long, default_value = "full", value_parser = parse_distortion)]
        distortion: DistortionModel,
        /// Camera id in the written camera table.
        #[arg(long, default_value = "camera")]
        id: String,
        /// Also write the camera table (rig file format) to this file.
        #[arg(long)]
        out: Option<PathBuf>,
        /// One JSON object instead of the report (docs/protocol.md).
        #[arg(long)]
        json: bool,
    },
    /// Fit the thesis's area-versus-distance models to samples (CSV area_px,distance).
    FitDepth {
        /// CSV with the header area_px,distance.
        #[arg(long)]
        samples: PathBuf,
        /// One JSON object per model per line.
        #[arg(long)]
        json: bool,
    },
    /// Repeat the thesis's four experiments in a simulation of its lab (docs/reproduce.md).
    Reproduce {
        /// Folder for the tables, plots and summary (replaced as a whole).
        #[arg(long, default_value = "reproduce")]
        out: PathBuf,
        #[arg(long, default_value_t = 1994)]
        seed: u64,
        /// Readings per height (the thesis took 25).
        #[arg(long, default_value_t = 25)]
        readings: usize,
        /// Gaussian noise, grey levels.
        #[arg(long, default_value_t = 2.0)]
        noise: f64,
        /// Skip the table of results at other noise levels (five more runs).
        #[arg(long)]
        no_noise_table: bool,
        /// Another lab: a rig file whose first two cameras look down at the floor.
        #[arg(long)]
        rig: Option<PathBuf>,
    },
    /// Run the whole live chain on a built-in synthetic rig: two cameras of the thesis's lab,
    /// three moving targets; shows poses against ground truth, then a summary.
    Demo {
        /// How long to measure, seconds from the first pose.
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// Run this rig file instead of the built-in one (synthetic cameras, no [[host]]).
        #[arg(long)]
        rig: Option<PathBuf>,
        /// No live table, only the summary.
        #[arg(long)]
        quiet: bool,
        /// The summary as one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// Start, watch and restart the services this PC runs in a rig file (docs/deploy.md).
    Run {
        /// The rig file.
        rig: PathBuf,
        /// This PC's name in the rig's [[host]] list (the only one if omitted).
        #[arg(long)]
        host: Option<String>,
        /// Prefix of iceoryx2's files (default: the host's iceoryx2_prefix).
        #[arg(long)]
        iox_prefix: Option<String>,
        /// Do not run a Zenoh router here (one runs already).
        #[arg(long)]
        no_router: bool,
    },
    /// Show every service of a rig on every PC: liveliness, rates, drops, errors, objects.
    Status {
        /// The rig file (its first host's router is asked; else give --connect and --rig-name).
        rig: Option<PathBuf>,
        /// A Zenoh router endpoint to ask (default: the rig's, else tcp/127.0.0.1:7447).
        #[arg(long)]
        connect: Option<String>,
        /// The rig's name, without a rig file.
        #[arg(long)]
        rig_name: Option<String>,
        /// Refresh every second until Ctrl-C.
        #[arg(long)]
        watch: bool,
        /// One JSON object.
        #[arg(long)]
        json: bool,
        /// Flag a camera with no processed frame for this long, milliseconds.
        #[arg(long, default_value_t = 2000)]
        stall_ms: u64,
    },
    /// Record a running rig's poses and observations into a session folder (docs/recording.md).
    Record {
        #[command(flatten)]
        args: stereoscope_recorder::cli::Args,
    },
    /// Re-run fusion on a recorded session and compare with its recorded poses; optionally
    /// publish its observations again on Zenoh.
    Replay {
        /// The session folder.
        session: PathBuf,
        /// Publish the recorded observations on Zenoh through this router endpoint (with
        /// --frames: the replay's own router listens there, for clients).
        #[arg(long)]
        publish: Option<String>,
        /// With --publish: as fast as possible instead of at the recorded pace.
        #[arg(long)]
        max_speed: bool,
        /// Feed the recorded frames (frames-<camera>.y4m) through capture, moment workers and
        /// fusion at the recorded pace, and compare the poses with the recorded ones.
        #[arg(long, conflicts_with = "max_speed")]
        frames: bool,
        /// With --frames: this many times the recorded pace (frames are dropped if a moment
        /// worker cannot keep up).
        #[arg(long, default_value_t = 1.0, requires = "frames")]
        speed: f64,
        /// The comparison as one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// Write a recorded session's poses in another format.
    Export {
        /// The session folder.
        session: PathBuf,
        /// csv (one row per object per pose frame) or c3d (markers per object, for
        /// biomechanics and animation tools; docs/recording.md).
        #[arg(long, value_parser = ["csv", "c3d"])]
        format: String,
        /// Output file (standard output if absent; required for c3d). Written whole or not at
        /// all.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Run one service in the foreground (what `run` starts; for debugging and deployment).
    #[command(subcommand)]
    Service(ServiceCommand),
    /// Triangulate points seen by a rig's cameras (CSV point,camera,u,v).
    Triangulate {
        /// The rig file (docs/rig.md).
        #[arg(long)]
        rig: PathBuf,
        /// CSV with the header point,camera,u,v (camera = a camera id of the rig).
        #[arg(long)]
        points: PathBuf,
        /// One JSON object per point per line.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Subcommand, Debug)]
enum ServiceCommand {
    /// Publish one camera's frames (V4L2, Y4M, images or the synthetic scene) into shared
    /// memory.
    Capture(stereoscope_capture::cli::Args),
    /// Track one camera's blobs (moments, tracking windows, heading) and publish observations.
    Moments(stereoscope_moments::cli::Args),
    /// Fuse every camera's observations into 3D poses with stable ids and publish them.
    Fusion(stereoscope_fusion::cli::Args),
    /// Send the pose stream to a serial port (the thesis's packet or the framed one).
    Serial(stereoscope_serial::cli::Args),
    /// Record poses, observations and optionally raw frames into a session folder.
    Recorder(stereoscope_recorder::cli::Args),
}

fn service(cmd: ServiceCommand) -> anyhow::Result<()> {
    match cmd {
        ServiceCommand::Capture(a) => stereoscope_capture::cli::main(a),
        ServiceCommand::Moments(a) => stereoscope_moments::cli::main(a),
        ServiceCommand::Fusion(a) => stereoscope_fusion::cli::main(a),
        ServiceCommand::Serial(a) => stereoscope_serial::cli::main(a),
        ServiceCommand::Recorder(a) => stereoscope_recorder::cli::main(a),
    }
}

/// The command that starts a service: this very binary with `service`.
fn service_program() -> anyhow::Result<Vec<String>> {
    let exe = std::env::current_exe()?;
    Ok(vec![exe.display().to_string(), "service".into()])
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("{s:?} is not WxH (e.g. 640x480)"))?;
    let p = |v: &str| {
        v.trim()
            .parse::<u32>()
            .ok()
            .filter(|&n| n > 0)
            .ok_or_else(|| format!("{s:?} is not WxH with positive whole numbers"))
    };
    Ok((p(w)?, p(h)?))
}

fn parse_distortion(s: &str) -> Result<DistortionModel, String> {
    match s {
        "none" => Ok(DistortionModel::None),
        "radial" => Ok(DistortionModel::Radial),
        "full" => Ok(DistortionModel::Full),
        _ => Err(format!(
            "{s:?} is not a distortion model: give none, radial or full"
        )),
    }
}

/// Exit status for a command that processed several inputs: 0 if all went well, 1 if some
/// failed (already reported), 1 with the message for a fatal error.
fn finish(result: anyhow::Result<usize>) -> ExitCode {
    match result {
        Ok(0) => ExitCode::SUCCESS,
        Ok(_) => ExitCode::from(1),
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}

fn parse_threshold(s: &str) -> Result<ThresholdMethod, String> {
    ThresholdMethod::parse(s)
        .ok_or_else(|| format!("{s:?} is not a threshold: give a number, auto, triangle or otsu"))
}

fn parse_connectivity(s: &str) -> Result<Connectivity, String> {
    match s {
        "4" => Ok(Connectivity::Four),
        "8" => Ok(Connectivity::Eight),
        _ => Err(format!("{s:?} is not a connectivity: give 4 or 8")),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Blobs {
            images,
            threshold,
            par,
            connectivity,
            min_area,
            json,
        } => {
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
        Command::Calibrate {
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
        } => {
            let source = match (points, dot_grid, spacing) {
                (Some(p), None, _) if images.is_empty() => Source::Points(p),
                (Some(_), None, _) => {
                    eprintln!(
                        "error: images are only read with --dot-grid (got --points and {} image(s))",
                        images.len()
                    );
                    return ExitCode::from(2);
                }
                (None, Some((cols, rows)), Some(spacing)) if !images.is_empty() => {
                    Source::DotGrid {
                        images,
                        cols: cols as usize,
                        rows: rows as usize,
                        spacing,
                    }
                }
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
        Command::Reproduce {
            out,
            seed,
            readings,
            noise,
            no_noise_table,
            rig,
        } => {
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
        Command::FitDepth { samples, json } => finish(
            fitdepth::run(
                &FitDepthOptions { samples, json },
                &mut std::io::stdout().lock(),
            )
            .map(|()| 0),
        ),
        Command::Service(cmd) => stereoscope_rig::exit::exit_code(service(cmd)),
        Command::Run {
            rig,
            host,
            iox_prefix,
            no_router,
        } => finish(stereoscope::live::run_rig(
            rig,
            host,
            iox_prefix,
            !no_router,
            service_program(),
        )),
        Command::Status {
            rig,
            connect,
            rig_name,
            watch,
            json,
            stall_ms,
        } => finish(stereoscope::live::status(
            rig, connect, rig_name, watch, json, stall_ms,
        )),
        Command::Record { args } => match stereoscope_recorder::cli::main(args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("error: {e:#}");
                ExitCode::from(1)
            }
        },
        Command::Replay {
            session,
            publish,
            frames: true,
            speed,
            json,
            ..
        } => finish(stereoscope::live::replay_frames(
            session,
            publish,
            speed,
            json,
            service_program(),
        )),
        Command::Replay {
            session,
            publish,
            max_speed,
            json,
            ..
        } => finish(stereoscope::live::replay(session, publish, max_speed, json)),
        Command::Export {
            session,
            format,
            out,
        } => finish(stereoscope::live::export(session, &format, out)),
        Command::Demo {
            seconds,
            rig,
            quiet,
            json,
        } => finish(stereoscope::live::demo(
            seconds,
            rig,
            !quiet && !json,
            json,
            service_program(),
        )),
        Command::Triangulate { rig, points, json } => {
            let opts = TriangulateOptions { rig, points, json };
            finish(triangulate::run(
                &opts,
                &mut std::io::stdout().lock(),
                &mut std::io::stderr().lock(),
            ))
        }
    }
}
