//! `meshwiki serve`: open the data directory and serve HTTP until SIGINT/SIGTERM.

use std::io::Write;

use anyhow::Context;
use meshwiki::web::{self, AppState};

use super::ServerArgs;

/// Runs `serve`.
pub async fn run(args: ServerArgs) -> anyhow::Result<()> {
    let state = AppState::open(args.settings()).await?;
    serve(state).await
}

/// What `serve` prints before each bound address (scripts and tests wait for it).
pub use meshwiki::config::LISTENING;

/// Serves an opened state, printing `meshwiki listening on http://ADDR` once bound.
pub async fn serve(state: AppState) -> anyhow::Result<()> {
    let bind = state.settings.bind.clone();
    web::run(state, |addrs| {
        let mut out = std::io::stdout().lock();
        for a in addrs {
            let _ = writeln!(out, "{LISTENING}http://{a}");
        }
        let _ = out.flush();
    })
    .await
    .with_context(|| format!("cannot serve on {bind}"))
}
