-- Background jobs: LOD builds of uploaded scans (`upload`), of local files imported with
-- `meshwiki import` (`file`) and of the generated demo relief (`demo`), with their progress.
-- A job is queued, then running, then done, failed or cancelled. A server that starts finds
-- jobs left `running` by a crash and queues them again (jobs of a `meshwiki import` process
-- that has died fail instead: their input belongs to that command line).

CREATE TABLE jobs (
    id               INTEGER PRIMARY KEY,
    kind             TEXT    NOT NULL CHECK (kind IN ('upload', 'file', 'demo')),
    model_id         INTEGER REFERENCES models (id) ON DELETE SET NULL,
    status           TEXT    NOT NULL DEFAULT 'queued'
                             CHECK (status IN ('queued', 'running', 'done', 'failed', 'cancelled')),
    -- upload: path relative to the data directory (uploads/src-<random>.<ext>);
    -- file: the path given to `meshwiki import`; demo: NULL.
    source_path      TEXT,
    -- Display name of the input (the uploader's file name: display only, never a path).
    source_name      TEXT    NOT NULL DEFAULT '',
    source_bytes     BIGINT  NOT NULL DEFAULT 0,
    -- Build options (JSON): memory_budget, max_patch_triangles, threads, triangles (demo).
    options          TEXT    NOT NULL DEFAULT '{}',
    stage            TEXT    NOT NULL DEFAULT '',
    done             BIGINT  NOT NULL DEFAULT 0,
    total            BIGINT  NOT NULL DEFAULT 0,
    percent          DOUBLE PRECISION NOT NULL DEFAULT 0,
    message          TEXT,
    -- The engine's build report (JSON) once done.
    report           TEXT,
    attempts         INTEGER NOT NULL DEFAULT 0,
    cancel_requested INTEGER NOT NULL DEFAULT 0 CHECK (cancel_requested IN (0, 1)),
    -- Process running the job (to tell a live `meshwiki import` from a crashed one).
    runner_pid       BIGINT,
    created_by       INTEGER REFERENCES users (id) ON DELETE SET NULL,
    created_at       TEXT    NOT NULL,
    started_at       TEXT,
    finished_at      TEXT,
    updated_at       TEXT    NOT NULL
);
CREATE INDEX jobs_status ON jobs (status, id);
CREATE INDEX jobs_model ON jobs (model_id);
