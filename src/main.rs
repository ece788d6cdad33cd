//! `fascicle`: the viewer (default), headless renderer and command-line tools.

use clap::Parser;
use fascicle::cli;

fn main() -> std::process::ExitCode {
    let args = cli::Cli::parse();
    let result: Result<(), String> = match args.command {
        Some(cli::Command::Fit { model }) => cli::fit::run(model).map_err(|e| e.to_string()),
        Some(cli::Command::Track(a)) => cli::track::run(a).map_err(|e| e.to_string()),
        Some(cli::Command::Peaks(a)) => cli::peaks::run(a).map_err(|e| e.to_string()),
        Some(cli::Command::Select(a)) => cli::select::run(a).map_err(|e| e.to_string()),
        Some(cli::Command::Info { file }) => cli::info::run(&file).map_err(|e| e.to_string()),
        Some(cli::Command::Render { scene, out, size, depth }) => {
            fascicle::render::run(scene.as_deref(), &out, &size, depth.as_deref())
        }
        Some(cli::Command::View { files, screenshot }) => {
            fascicle::viewer::run(files, screenshot);
            Ok(())
        }
        None => {
            fascicle::viewer::run(vec![], None);
            Ok(())
        }
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
