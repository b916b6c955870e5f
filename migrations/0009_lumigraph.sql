-- The network mode of the system paper (§5, issue 12): each model's Grid-Lumigraph image
-- repository, built by a background job of kind `lumigraph`, and who may read its geometry.

-- Jobs gain the kind `lumigraph` (SQLite cannot alter a CHECK: the table is rebuilt, rows and
-- ids kept). A lumigraph job renders the repository of a ready model; unlike a build it never
-- changes the model's status.
CREATE TABLE jobs_new (
    id               INTEGER PRIMARY KEY,
    kind             TEXT    NOT NULL CHECK (kind IN ('upload', 'file', 'demo', 'lumigraph')),
    model_id         INTEGER REFERENCES models (id) ON DELETE SET NULL,
    status           TEXT    NOT NULL DEFAULT 'queued'
                             CHECK (status IN ('queued', 'running', 'done', 'failed', 'cancelled')),
    source_path      TEXT,
    source_name      TEXT    NOT NULL DEFAULT '',
    source_bytes     BIGINT  NOT NULL DEFAULT 0,
    -- Build options (JSON): memory_budget, max_patch_triangles, threads, triangles (demo);
    -- grid, size (lumigraph).
    options          TEXT    NOT NULL DEFAULT '{}',
    stage            TEXT    NOT NULL DEFAULT '',
    done             BIGINT  NOT NULL DEFAULT 0,
    total            BIGINT  NOT NULL DEFAULT 0,
    percent          DOUBLE PRECISION NOT NULL DEFAULT 0,
    message          TEXT,
    report           TEXT,
    attempts         INTEGER NOT NULL DEFAULT 0,
    cancel_requested INTEGER NOT NULL DEFAULT 0 CHECK (cancel_requested IN (0, 1)),
    runner_pid       BIGINT,
    created_by       INTEGER REFERENCES users (id) ON DELETE SET NULL,
    created_at       TEXT    NOT NULL,
    started_at       TEXT,
    finished_at      TEXT,
    updated_at       TEXT    NOT NULL
);
INSERT INTO jobs_new SELECT id, kind, model_id, status, source_path, source_name, source_bytes,
    options, stage, done, total, percent, message, report, attempts, cancel_requested,
    runner_pid, created_by, created_at, started_at, finished_at, updated_at FROM jobs;
DROP TABLE jobs;
ALTER TABLE jobs_new RENAME TO jobs;
CREATE INDEX jobs_status ON jobs (status, id);
CREATE INDEX jobs_model ON jobs (model_id);

-- A model's repository: the grid it was asked for and where its build stands. Rebuilding
-- replaces it; deleting the model deletes it.
CREATE TABLE lumigraphs (
    model_id     INTEGER PRIMARY KEY REFERENCES models (id) ON DELETE CASCADE,
    -- Points per axis of the grid and side of each image in pixels.
    grid         INTEGER NOT NULL CHECK (grid >= 2),
    size         INTEGER NOT NULL CHECK (size >= 16),
    status       TEXT    NOT NULL DEFAULT 'queued'
                         CHECK (status IN ('queued', 'building', 'ready', 'failed')),
    job_id       INTEGER REFERENCES jobs (id) ON DELETE SET NULL,
    message      TEXT,
    -- Render time of the finished repository, in seconds (all attempts).
    seconds      DOUBLE PRECISION NOT NULL DEFAULT 0,
    created_at   TEXT    NOT NULL,
    updated_at   TEXT    NOT NULL
);

-- Its images, keyed as in the paper by grid point and direction (0..5: +x, -x, +y, -y, +z,
-- -z). `kind`: `image` (stored under `lumigraph/` by the SHA-256 of its bytes), `empty` (the
-- image shows nothing) or `inside` (the grid point lies inside the object). A grid point's
-- six rows are written in one transaction: a build resumes at the first point without rows.
CREATE TABLE lumigraph_images (
    model_id   INTEGER NOT NULL REFERENCES lumigraphs (model_id) ON DELETE CASCADE,
    x          INTEGER NOT NULL,
    y          INTEGER NOT NULL,
    z          INTEGER NOT NULL,
    d          INTEGER NOT NULL CHECK (d BETWEEN 0 AND 5),
    kind       TEXT    NOT NULL CHECK (kind IN ('image', 'empty', 'inside')),
    sha256     TEXT,
    bytes      BIGINT  NOT NULL DEFAULT 0,
    PRIMARY KEY (model_id, x, y, z, d),
    CHECK ((kind = 'image') = (sha256 IS NOT NULL))
) WITHOUT ROWID;
CREATE INDEX lumigraph_images_sha ON lumigraph_images (sha256);

-- Who may read the model's geometry: `full` (anyone who may view the model) or `sparse`
-- (only admins get patches finer than the sparse mesh, the LOD file, exports and depth
-- buffers; everyone else views it image-based).
ALTER TABLE models ADD COLUMN geometry_access TEXT NOT NULL DEFAULT 'full'
    CHECK (geometry_access IN ('full', 'sparse'));
