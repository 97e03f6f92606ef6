//! `stereoscope`: the command line. Parses arguments and calls the library.

use clap::{Parser, Subcommand};

mod args;
use std::process::ExitCode;
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
    Blobs(args::BlobsArgs),
    /// Calibrate a camera from target points (CSV view,X,Y,Z,u,v) or from dot-grid images.
    Calibrate(args::CalibrateArgs),
    /// Fit the thesis's area-versus-distance models to samples (CSV area_px,distance).
    FitDepth(args::FitDepthArgs),
    /// Repeat the thesis's four experiments in a simulation of its lab (docs/reproduce.md).
    Reproduce(args::ReproduceArgs),
    /// Run the whole live chain on a built-in synthetic rig: two cameras of the thesis's lab,
    /// three moving targets; shows poses against ground truth, then a summary.
    Demo(args::DemoArgs),
    /// Start, watch and restart the services this PC runs in a rig file (docs/deploy.md).
    Run(args::RunArgs),
    /// Show every service of a rig on every PC: liveliness, rates, drops, errors, objects.
    Status(args::StatusArgs),
    /// Serve the live view of a running rig in a browser: the 3D scene, each camera's
    /// monitor, the services' health (docs/viewer.md).
    View(args::ViewArgs),
    /// Record a running rig's poses and observations into a session folder (docs/recording.md).
    Record {
        #[command(flatten)]
        args: stereoscope_recorder::cli::Args,
    },
    /// Re-run fusion on a recorded session and compare with its recorded poses; optionally
    /// publish its observations again on Zenoh.
    Replay(args::ReplayArgs),
    /// Write a recorded session's poses in another format.
    Export(args::ExportArgs),
    /// Run one service in the foreground (what `run` starts; for debugging and deployment).
    #[command(subcommand)]
    Service(ServiceCommand),
    /// Triangulate points seen by a rig's cameras (CSV point,camera,u,v).
    Triangulate(args::TriangulateArgs),
    /// Rigid bodies: define one from the markers the running rig sees now.
    #[command(subcommand)]
    Body(BodyCommand),
    /// Kinematic models: define one's markers and measure its links from a recorded
    /// range-of-motion take.
    #[command(subcommand)]
    Model(ModelCommand),
    /// Save frames of one camera (for calibration) and a preview of what its moment worker
    /// finds in them, to aim the camera and set its exposure.
    Grab(args::GrabArgs),
    /// Fuse a rig's recorded video offline, as fast as the machine goes: every camera's file
    /// (Y4M, images, the synthetic scene) frame by frame in step, into a session folder.
    Process(args::ProcessArgs),
    /// Calibration targets to print.
    #[command(subcommand)]
    Target(TargetCommand),
}

#[derive(Subcommand, Debug)]
enum TargetCommand {
    /// A dot grid (the target `calibrate --dot-grid` finds) as an SVG or PDF page to print at
    /// true size, its axes and origin dot marked.
    DotGrid(args::DotGridTargetArgs),
}

#[derive(Subcommand, Debug)]
enum BodyCommand {
    /// Take the loose markers tracked now (3–8, held still; --objects or --inside to choose),
    /// average them over --seconds and print the [[body]] table (origin and axes as --origin
    /// and --axes ask: the centroid and the world's by default); --write appends it to the rig
    /// file.
    Define(args::BodyDefineArgs),
}

#[derive(Subcommand, Debug)]
enum ModelCommand {
    /// From a recorded take that moves every joint and one of the model standing at its zero
    /// pose (--home): find which markers ride on which link, the joints' centres and axes, the
    /// link lengths against the skeleton (--urdf, or the rig's [[model]] of that name), and
    /// print the [[model]] table with the markers placed; --write puts it in the rig file.
    Define(args::ModelDefineArgs),
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
    /// Send rigid bodies to VR and robot applications (VRPN, VMT/VMC over OSC, opentrack).
    Vrfeed(stereoscope_vrfeed::cli::Args),
    /// Record poses, observations and optionally raw frames into a session folder.
    Recorder(stereoscope_recorder::cli::Args),
    /// Serve the live view in a browser (what `view` runs).
    Viewer(stereoscope_viewer::cli::Args),
    /// Run only this host's Zenoh router (with the rig's TLS and access control).
    Router(stereoscope_launcher::router_cli::Args),
}

fn service(cmd: ServiceCommand) -> anyhow::Result<()> {
    match cmd {
        ServiceCommand::Capture(a) => stereoscope_service::run(a),
        ServiceCommand::Moments(a) => stereoscope_service::run(a),
        ServiceCommand::Fusion(a) => stereoscope_service::run(a),
        ServiceCommand::Serial(a) => stereoscope_service::run(a),
        ServiceCommand::Vrfeed(a) => stereoscope_service::run(a),
        ServiceCommand::Recorder(a) => stereoscope_service::run(a),
        ServiceCommand::Router(a) => stereoscope_service::run(a),
        ServiceCommand::Viewer(a) => stereoscope_service::run(a),
    }
}

/// The command that starts a service: this very binary with `service`.
fn service_program() -> anyhow::Result<Vec<String>> {
    let exe = std::env::current_exe()?;
    Ok(vec![exe.display().to_string(), "service".into()])
}

/// A command-line value that is not one of its kind (clap names the flag).
#[derive(Debug, thiserror::Error)]
enum BadValue {
    #[error("{0:?} is not WxH with positive whole numbers (e.g. 640x480)")]
    Size(String),
    #[error("{0:?} is not a distortion model: give none, radial, tangential or full")]
    Distortion(String),
    #[error("{0:?} is not a threshold: give a number, auto, triangle or otsu")]
    Threshold(String),
    #[error("{0:?} is not a connectivity: give 4 or 8")]
    Connectivity(String),
}

fn parse_size(s: &str) -> Result<(u32, u32), BadValue> {
    let bad = || BadValue::Size(s.to_string());
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let p = |v: &str| {
        v.trim()
            .parse::<u32>()
            .ok()
            .filter(|&n| n > 0)
            .ok_or_else(bad)
    };
    Ok((p(w)?, p(h)?))
}

fn parse_distortion(s: &str) -> Result<DistortionModel, BadValue> {
    match s {
        "none" => Ok(DistortionModel::None),
        "radial" => Ok(DistortionModel::Radial),
        "tangential" => Ok(DistortionModel::Tangential),
        "full" => Ok(DistortionModel::Full),
        _ => Err(BadValue::Distortion(s.to_string())),
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

fn parse_threshold(s: &str) -> Result<ThresholdMethod, BadValue> {
    ThresholdMethod::parse(s).ok_or_else(|| BadValue::Threshold(s.to_string()))
}

fn parse_connectivity(s: &str) -> Result<Connectivity, BadValue> {
    match s {
        "4" => Ok(Connectivity::Four),
        "8" => Ok(Connectivity::Eight),
        _ => Err(BadValue::Connectivity(s.to_string())),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Blobs(a) => a.run(),
        Command::Calibrate(a) => a.run(),
        Command::Target(TargetCommand::DotGrid(a)) => a.run(),
        Command::Grab(a) => a.run(),
        Command::Process(a) => a.run(),
        Command::Reproduce(a) => a.run(),
        Command::FitDepth(args::FitDepthArgs { samples, json }) => finish(
            fitdepth::run(
                &FitDepthOptions { samples, json },
                &mut std::io::stdout().lock(),
            )
            .map(|()| 0),
        ),
        Command::Service(cmd) => stereoscope_service::exit::exit_code(service(cmd)),
        Command::Run(args::RunArgs {
            rig,
            place,
            no_router,
        }) => {
            // Like a service: a rig it refuses (or a service refused) ends with the
            // configuration status, so whatever supervises `run` does not restart it.
            let result = stereoscope::live::run_rig(rig, place, !no_router, service_program());
            let refused = result.as_ref().err().is_some_and(|e| {
                e.chain().any(|c| {
                    matches!(
                        c.downcast_ref::<stereoscope_launcher::LaunchError>(),
                        Some(
                            stereoscope_launcher::LaunchError::ServiceConfig { .. }
                                | stereoscope_launcher::LaunchError::Realtime { .. }
                        )
                    )
                })
            });
            match result {
                Err(e) if refused => {
                    eprintln!("error: {e:#}");
                    ExitCode::from(stereoscope_service::exit::CONFIG_EXIT_STATUS)
                }
                r => stereoscope_service::exit::exit_code(r.map(|_| ())),
            }
        }
        Command::Model(ModelCommand::Define(a)) => {
            let json = a.json;
            match stereoscope::model::define(&a.into_options()) {
                Ok(d) => {
                    if json {
                        println!("{}", d.json);
                    } else {
                        eprint!("{}", d.report);
                        print!("{}", d.table);
                    }
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("error: {e:#}");
                    ExitCode::from(1)
                }
            }
        }
        Command::Body(BodyCommand::Define(a)) => match match &a.session {
            Some(dir) => {
                stereoscope::body::define_from_session(&a.name, &a.rig, dir, a.write, &a.choice())
            }
            None => stereoscope::body::define_live(
                &a.name,
                &a.rig,
                a.connect.clone(),
                a.seconds,
                a.write,
                a.tls.clone(),
                &a.choice(),
            ),
        } {
            Ok(text) => {
                print!("{text}");
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("error: {e:#}");
                ExitCode::from(1)
            }
        },
        Command::Status(args::StatusArgs {
            rig,
            connect,
            rig_name,
            watch,
            json,
            stall_ms,
            tls,
        }) => finish(stereoscope::live::status(
            rig, connect, rig_name, watch, json, stall_ms, tls,
        )),
        Command::Record { args } => match stereoscope_service::run(args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("error: {e:#}");
                ExitCode::from(1)
            }
        },
        Command::Replay(args::ReplayArgs {
            session,
            rig: Some(rig),
            out: Some(out),
            ..
        }) => finish(stereoscope::sessions::refuse_with_rig(session, rig, out)),
        Command::Replay(args::ReplayArgs {
            session,
            publish,
            frames: true,
            speed,
            json,
            ..
        }) => finish(stereoscope::sessions::replay_frames(
            session,
            publish,
            speed,
            json,
            service_program(),
        )),
        Command::Replay(args::ReplayArgs {
            session,
            publish,
            max_speed,
            json,
            ..
        }) => finish(stereoscope::sessions::replay(
            session, publish, max_speed, json,
        )),
        Command::Export(args::ExportArgs {
            session,
            format,
            out,
            fill_gaps,
        }) => finish(stereoscope::sessions::export(
            session,
            &format,
            out,
            fill_gaps.map(|n| n as usize),
        )),
        Command::Demo(args::DemoArgs {
            seconds,
            rig,
            quiet,
            json,
            view,
            view_listen,
        }) => finish(stereoscope::live::demo(
            seconds,
            rig,
            !quiet && !json,
            json,
            view.then_some(view_listen),
            service_program(),
        )),
        Command::View(a) => {
            stereoscope_service::exit::exit_code(stereoscope_service::run(a.into_service_args()))
        }
        Command::Triangulate(args::TriangulateArgs { rig, points, json }) => {
            let opts = TriangulateOptions { rig, points, json };
            finish(triangulate::run(
                &opts,
                &mut std::io::stdout().lock(),
                &mut std::io::stderr().lock(),
            ))
        }
    }
}
