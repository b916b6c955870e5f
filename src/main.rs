//! `meshwiki` command line: parse, set up logging, dispatch to [`cli`].

mod cli;

use clap::Parser;

fn main() -> std::process::ExitCode {
    let args = cli::Cli::parse();
    meshwiki::terminal::init_logging();
    let result = actix_web::rt::System::new().block_on(cli::run(args));
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
