//! `fascicle-bench`: the benchmark suites and the soak run, kept out of the `fascicle` binary users install (they
//! link a plotting library and drive many headless renders). Each suite prints Markdown tables; `all` writes the
//! report with plots.

mod bench_all;
mod bench_edits;
mod bench_fits;
mod bench_glyphs;
mod bench_interact;
mod bench_scale;
mod bench_splats;
mod bench_tracking;
mod bench_tracts;
mod bench_volume;
mod seed;
mod soak;
mod suites;

use clap::Parser;

#[derive(Parser, Debug)]
#[command(name = "fascicle-bench", version, about = "Fascicle's benchmark suites and soak run")]
struct Cli {
    #[command(subcommand)]
    suite: suites::BenchCommand,
}

fn main() -> std::process::ExitCode {
    // SAFETY: before any thread starts; the renders measured in this process see what `fascicle` sees.
    unsafe { fascicle_render::software::oversubscribe_software_rasterizer() };
    let cli = Cli::parse();
    match suites::run(cli.suite) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
