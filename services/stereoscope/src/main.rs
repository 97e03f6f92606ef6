//! `stereoscope`: the command line. Parses arguments and calls the library.

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use stereoscope::blobs::{self, BlobsOptions};
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
    }
}
