//! `meshwiki-bench search`: generate contents into a scratch database, build the search
//! index from it (the `reindex` path) and measure query latency. Prints figures; asserts
//! nothing.

use std::time::Instant;

use anyhow::Context;
use clap::Args as ClapArgs;
use meshwiki::search::SearchIndex;
use meshwiki::store::Db;
use meshwiki::store::contents::{self, ContentEdit};
use meshwiki::store::users::{self, Role};

use crate::DataDirArgs;

/// Options of `bench search`.
#[derive(Debug, Clone, ClapArgs)]
pub struct Args {
    /// Data directory; the benchmark works in a scratch sub-directory it removes afterwards.
    #[command(flatten)]
    pub data: DataDirArgs,
    /// Contents to generate.
    #[arg(long, default_value_t = 100_000)]
    pub docs: usize,
    /// Queries to time.
    #[arg(long, default_value_t = 1_000)]
    pub queries: usize,
    /// Keep the scratch directory.
    #[arg(long)]
    pub keep: bool,
}

/// splitmix64: a small deterministic generator, enough for synthetic text.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }

    /// Roughly Zipf-distributed index in `0..n` (frequent words are frequent).
    fn zipf(&mut self, n: usize) -> usize {
        let u = (self.next() >> 11) as f64 / (1u64 << 53) as f64;
        (((n as f64).powf(u)) as usize).saturating_sub(1).min(n - 1)
    }
}

fn vocabulary(rng: &mut Rng, n: usize) -> Vec<String> {
    const ONSETS: &[&str] = &[
        "b", "c", "d", "f", "g", "k", "l", "m", "n", "p", "r", "s", "t", "v", "z", "br", "st",
        "tr", "gl", "pl",
    ];
    const VOWELS: &[&str] = &["a", "e", "i", "o", "u", "ae", "io", "ou"];
    const CODAS: &[&str] = &["", "n", "r", "s", "l", "m", "x", "nt", "rd"];
    let mut words = std::collections::BTreeSet::new();
    while words.len() < n {
        let syllables = 2 + rng.below(2);
        let mut w = String::new();
        for _ in 0..syllables {
            w.push_str(ONSETS[rng.below(ONSETS.len())]);
            w.push_str(VOWELS[rng.below(VOWELS.len())]);
        }
        w.push_str(CODAS[rng.below(CODAS.len())]);
        words.insert(w);
    }
    let mut v: Vec<String> = words.into_iter().collect();
    // Shuffle so frequency does not follow alphabetical order.
    for i in (1..v.len()).rev() {
        let j = rng.below(i + 1);
        v.swap(i, j);
    }
    v
}

fn sentence(rng: &mut Rng, vocab: &[String], words: usize) -> String {
    let mut s = String::new();
    for i in 0..words {
        if i > 0 {
            s.push(' ');
        }
        s.push_str(&vocab[rng.zipf(vocab.len())]);
    }
    s
}

fn generate(rng: &mut Rng, vocab: &[String], i: usize) -> ContentEdit {
    let n = 3 + rng.below(4);
    let title = sentence(rng, vocab, n);
    let n = 6 + rng.below(6);
    let caption = sentence(rng, vocab, n);
    let mut body = format!("# {title}\n\n");
    for p in 0..(2 + rng.below(3)) {
        if p == 1 {
            body.push_str(&format!("## {}\n\n", sentence(rng, vocab, 3)));
        }
        let n = 30 + rng.below(50);
        body.push_str(&sentence(rng, vocab, n));
        body.push_str(".\n\n");
    }
    body.push_str(&format!(
        "- item **{}**\n- ref `{i}`\n",
        vocab[rng.below(vocab.len())]
    ));
    ContentEdit {
        title,
        caption,
        body,
        comment: "generated".into(),
    }
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let idx = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[idx.min(sorted.len() - 1)]
}

fn dir_size(path: &std::path::Path) -> u64 {
    std::fs::read_dir(path)
        .map(|rd| {
            rd.filter_map(Result::ok)
                .map(|e| match e.metadata() {
                    Ok(m) if m.is_dir() => dir_size(&e.path()),
                    Ok(m) => m.len(),
                    Err(_) => 0,
                })
                .sum()
        })
        .unwrap_or(0)
}

/// Runs `bench search`.
pub async fn run(args: Args) -> anyhow::Result<()> {
    let scratch = args
        .data
        .data_dir
        .join(format!("bench-search-{}", std::process::id()));
    let settings = meshwiki::Settings::new(&scratch);
    settings
        .ensure_dirs()
        .with_context(|| format!("cannot create {}", scratch.display()))?;
    let result = bench(&args, &settings).await;
    if !args.keep {
        let _ = std::fs::remove_dir_all(&scratch);
    }
    result
}

async fn bench(args: &Args, settings: &meshwiki::Settings) -> anyhow::Result<()> {
    let docs = args.docs.max(1);
    let db = Db::open(&settings.db_path()).await?;
    let user = users::create(&db, "bench", "bench-password", Role::Editor, None).await?;
    let mut rng = Rng(0x5EED_CAFE);
    let vocab = vocabulary(&mut rng, 20_000);

    println!(
        "bench search: {docs} generated contents, {} queries",
        args.queries
    );
    let start = Instant::now();
    let mut tx = db.begin().await?;
    for i in 0..docs {
        let edit = generate(&mut rng, &vocab, i);
        contents::create_tx(&mut tx, &edit, None, user.id).await?;
    }
    tx.commit().await?;
    println!(
        "  database insert:   {:>9.2} s",
        start.elapsed().as_secs_f64()
    );

    let start = Instant::now();
    let index = SearchIndex::open(&settings.index_dir(), &db).await?;
    let build = start.elapsed().as_secs_f64();
    println!(
        "  index build:       {:>9.2} s  ({:.0} contents/s, {} documents, {:.1} MiB on disk)",
        build,
        docs as f64 / build,
        index.num_docs(),
        dir_size(&settings.index_dir()) as f64 / (1024.0 * 1024.0)
    );

    let queries: Vec<String> = (0..args.queries.max(1))
        .map(|i| {
            // Mix of one- and two-word queries over frequent and rare words.
            let a = &vocab[rng.zipf(vocab.len() / 4)];
            if i % 3 == 0 {
                format!("{a} {}", vocab[rng.zipf(vocab.len() / 4)])
            } else {
                a.clone()
            }
        })
        .collect();
    let search = index.clone();
    let (latencies, hits) = tokio::task::spawn_blocking(move || {
        let mut lat = Vec::with_capacity(queries.len());
        let mut hits = 0usize;
        for q in &queries {
            let t = Instant::now();
            let r = search.search(q, None, 10, 0)?;
            lat.push(t.elapsed().as_secs_f64() * 1000.0);
            hits += r.hits.len();
        }
        Ok::<_, meshwiki::search::SearchError>((lat, hits))
    })
    .await??;
    let mut sorted = latencies.clone();
    sorted.sort_by(f64::total_cmp);
    let mean = sorted.iter().sum::<f64>() / sorted.len() as f64;
    println!(
        "  query latency:     p50 {:.2} ms, p99 {:.2} ms, mean {:.2} ms, max {:.2} ms (top 10 with snippets, {} hits)",
        percentile(&sorted, 0.50),
        percentile(&sorted, 0.99),
        mean,
        sorted.last().copied().unwrap_or(0.0),
        hits
    );
    db.close().await;
    Ok(())
}
