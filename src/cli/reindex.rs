//! `meshwiki reindex`: rebuild the search index from the database.

use std::time::Instant;

use anyhow::Context;
use meshwiki::search::SearchIndex;
use meshwiki::store::Db;

use super::DataDirArgs;

/// Runs `reindex`.
pub async fn run(args: DataDirArgs) -> anyhow::Result<()> {
    let settings = meshwiki::Settings::new(&args.data_dir);
    settings
        .ensure_dirs()
        .with_context(|| format!("cannot prepare {}", settings.data_dir.display()))?;
    let db = Db::open(&settings.db_path()).await?;
    let start = Instant::now();
    let index = SearchIndex::open(&settings.index_dir(), &db)
        .await
        .context("cannot open the search index (is the server running? stop it first)")?;
    let n = index.rebuild(&db).await?;
    db.close().await;
    println!(
        "reindexed {n} contents in {:.2} s",
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
