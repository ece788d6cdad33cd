//! `fascicle`: the viewer (default), headless renderer and command-line tools.

use clap::Parser;
use fascicle::cli;

fn main() -> std::process::ExitCode {
    // A closed stdout (`fascicle info F | head`) ends the command quietly, as for any Unix tool, instead of a
    // panic in `println!`.
    #[cfg(unix)]
    // SAFETY: restoring the default action of SIGPIPE before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // SAFETY: before any thread starts. Lavapipe on few cores keeps a frame's binned lines (GBs) otherwise.
    unsafe { fascicle_render::software::oversubscribe_software_rasterizer() };
    let args = cli::Cli::parse();
    if let Err(e) = cli::set_globals(&args) {
        eprintln!("error: {e}");
        return std::process::ExitCode::from(2);
    }
    let result: Result<(), String> = match args.command {
        Some(cli::Command::Fit { model }) => cli::fit::run(model).map_err(|e| e.to_string()),
        Some(cli::Command::Track(a)) => cli::track::run(a).map_err(|e| e.to_string()),
        Some(cli::Command::Peaks(a)) => cli::peaks::run(a).map_err(|e| e.to_string()),
        Some(cli::Command::Select(a)) => cli::select::run(a).map_err(|e| e.to_string()),
        Some(cli::Command::Convert { input, output, sh_basis }) => {
            cli::convert::run(&input, &output, sh_basis.map(Into::into)).map_err(|e| e.to_string())
        }
        Some(cli::Command::Info { file, json }) => cli::info::run(&file, json).map_err(|e| e.to_string()),
        Some(cli::Command::Render { scene, out, size, depth, ortho, crosshair }) => {
            cli::check_output(&out).map_err(|e| e.to_string()).and_then(|()| {
                let views = fascicle::render::ViewOptions { ortho, crosshair: crosshair.as_deref() };
                fascicle::render::run(scene.as_deref(), &out, &size, depth.as_deref(), views)
            })
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
