//! `fascicle`: the viewer (default), headless renderer and command-line tools.

use clap::Parser;

mod cli;

fn main() -> std::process::ExitCode {
    let args = cli::Cli::parse();
    let result = match args.command {
        Some(cli::Command::Fit { model }) => cli::fit::run(model),
        Some(cli::Command::Info { file }) => cli::info::run(&file),
        Some(cli::Command::Render { .. }) | Some(cli::Command::View { .. }) | None => {
            eprintln!("viewer/render: not yet wired");
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
