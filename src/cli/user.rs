//! `meshwiki user add NAME --role ROLE`: create an account; the password is read from the
//! first line of standard input.

use std::io::{BufRead, IsTerminal, Write};

use anyhow::{Context, bail};
use clap::Args;
use meshwiki::store::Db;
use meshwiki::store::users::{self, Role};

use super::DataDirArgs;

/// Options of `user add`.
#[derive(Debug, Clone, Args)]
pub struct AddArgs {
    /// Data directory.
    #[command(flatten)]
    pub data: DataDirArgs,
    /// User name.
    pub name: String,
    /// Role: admin, editor or viewer.
    #[arg(long, value_parser = parse_role)]
    pub role: Role,
}

fn parse_role(s: &str) -> Result<Role, String> {
    s.parse()
}

/// Runs `user add`.
pub async fn add(args: AddArgs) -> anyhow::Result<()> {
    let stdin = std::io::stdin();
    if stdin.is_terminal() {
        eprint!("Password for {} (input is visible): ", args.name);
        let _ = std::io::stderr().flush();
    }
    let mut line = String::new();
    stdin
        .lock()
        .read_line(&mut line)
        .context("cannot read the password from standard input")?;
    let password = line.trim_end_matches(['\n', '\r']);
    if password.is_empty() {
        bail!("no password on standard input");
    }
    let settings = meshwiki::Settings::new(&args.data.data_dir);
    settings
        .ensure_dirs()
        .with_context(|| format!("cannot prepare {}", settings.data_dir.display()))?;
    let db = Db::open(&settings.db_path()).await?;
    let user = users::create(&db, &args.name, password, args.role, None).await?;
    db.close().await;
    println!(
        "created user {} ({}) with id {}",
        user.username, user.role, user.id
    );
    Ok(())
}
