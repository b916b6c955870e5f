-- meshwiki initial schema (system paper §2.1.2: Identified Part, Information Contents,
-- Assigned Information). Kept close to portable SQL: on PostgreSQL replace
-- `INTEGER PRIMARY KEY` by `BIGINT GENERATED ALWAYS AS IDENTITY PRIMARY KEY` and BLOB by BYTEA.
-- Timestamps are RFC 3339 UTC strings; session expiry is Unix seconds.

CREATE TABLE users (
    id            INTEGER PRIMARY KEY,
    username      TEXT    NOT NULL UNIQUE,
    password_hash TEXT    NOT NULL,
    role          TEXT    NOT NULL CHECK (role IN ('admin', 'editor', 'viewer')),
    disabled      INTEGER NOT NULL DEFAULT 0 CHECK (disabled IN (0, 1)),
    created_at    TEXT    NOT NULL,
    updated_at    TEXT    NOT NULL
);

CREATE TABLE sessions (
    id         INTEGER PRIMARY KEY,
    token_hash TEXT    NOT NULL UNIQUE,
    user_id    INTEGER NOT NULL REFERENCES users (id) ON DELETE CASCADE,
    csrf_token TEXT    NOT NULL,
    created_at TEXT    NOT NULL,
    expires_at BIGINT  NOT NULL
);
CREATE INDEX sessions_user ON sessions (user_id);
CREATE INDEX sessions_expiry ON sessions (expires_at);

CREATE TABLE attachments (
    id            INTEGER PRIMARY KEY,
    sha256        TEXT    NOT NULL,
    media_type    TEXT    NOT NULL,
    size          BIGINT  NOT NULL,
    original_name TEXT    NOT NULL,
    uploaded_by   INTEGER NOT NULL REFERENCES users (id),
    created_at    TEXT    NOT NULL
);
CREATE INDEX attachments_sha256 ON attachments (sha256);

CREATE TABLE models (
    id                      INTEGER PRIMARY KEY,
    title                   TEXT    NOT NULL,
    description             TEXT    NOT NULL DEFAULT '',
    source_name             TEXT    NOT NULL DEFAULT '',
    status                  TEXT    NOT NULL DEFAULT 'pending'
                                    CHECK (status IN ('pending', 'building', 'ready', 'failed')),
    vertex_count            BIGINT  NOT NULL DEFAULT 0,
    triangle_count          BIGINT  NOT NULL DEFAULT 0,
    bbox_min_x              DOUBLE PRECISION,
    bbox_min_y              DOUBLE PRECISION,
    bbox_min_z              DOUBLE PRECISION,
    bbox_max_x              DOUBLE PRECISION,
    bbox_max_y              DOUBLE PRECISION,
    bbox_max_z              DOUBLE PRECISION,
    lod_path                TEXT,
    error                   TEXT,
    thumbnail_attachment_id INTEGER REFERENCES attachments (id) ON DELETE SET NULL,
    created_by              INTEGER NOT NULL REFERENCES users (id),
    created_at              TEXT    NOT NULL,
    updated_at              TEXT    NOT NULL
);

CREATE TABLE parts (
    id                      INTEGER PRIMARY KEY,
    model_id                INTEGER NOT NULL REFERENCES models (id) ON DELETE CASCADE,
    kind                    TEXT    NOT NULL CHECK (kind IN ('point', 'region')),
    center_x                DOUBLE PRECISION NOT NULL,
    center_y                DOUBLE PRECISION NOT NULL,
    center_z                DOUBLE PRECISION NOT NULL,
    vertex_count            BIGINT  NOT NULL DEFAULT 0,
    vertex_set              BLOB,
    camera                  TEXT,
    thumbnail_attachment_id INTEGER REFERENCES attachments (id) ON DELETE SET NULL,
    created_by              INTEGER NOT NULL REFERENCES users (id),
    created_at              TEXT    NOT NULL,
    updated_at              TEXT    NOT NULL
);
CREATE INDEX parts_model ON parts (model_id);

CREATE TABLE contents (
    id                      INTEGER PRIMARY KEY,
    title                   TEXT    NOT NULL,
    caption                 TEXT    NOT NULL DEFAULT '',
    body                    TEXT    NOT NULL DEFAULT '',
    thumbnail_attachment_id INTEGER REFERENCES attachments (id) ON DELETE SET NULL,
    current_revision        INTEGER NOT NULL,
    created_by              INTEGER NOT NULL REFERENCES users (id),
    created_at              TEXT    NOT NULL,
    updated_at              TEXT    NOT NULL
);

CREATE TABLE content_revisions (
    id         INTEGER PRIMARY KEY,
    content_id INTEGER NOT NULL REFERENCES contents (id) ON DELETE CASCADE,
    number     INTEGER NOT NULL,
    title      TEXT    NOT NULL,
    caption    TEXT    NOT NULL,
    body       TEXT    NOT NULL,
    author_id  INTEGER NOT NULL REFERENCES users (id),
    comment    TEXT    NOT NULL DEFAULT '',
    created_at TEXT    NOT NULL,
    UNIQUE (content_id, number)
);

CREATE TABLE content_attachments (
    content_id    INTEGER NOT NULL REFERENCES contents (id) ON DELETE CASCADE,
    attachment_id INTEGER NOT NULL REFERENCES attachments (id) ON DELETE CASCADE,
    position      INTEGER NOT NULL,
    PRIMARY KEY (content_id, attachment_id)
);
CREATE INDEX content_attachments_attachment ON content_attachments (attachment_id);

CREATE TABLE assignments (
    id         INTEGER PRIMARY KEY,
    part_id    INTEGER NOT NULL REFERENCES parts (id) ON DELETE CASCADE,
    content_id INTEGER NOT NULL REFERENCES contents (id) ON DELETE CASCADE,
    position   INTEGER NOT NULL,
    created_by INTEGER NOT NULL REFERENCES users (id),
    created_at TEXT    NOT NULL,
    UNIQUE (part_id, content_id)
);
CREATE INDEX assignments_content ON assignments (content_id);

CREATE TABLE audit_log (
    id         INTEGER PRIMARY KEY,
    user_id    INTEGER REFERENCES users (id) ON DELETE SET NULL,
    action     TEXT    NOT NULL,
    entity     TEXT    NOT NULL,
    entity_id  BIGINT,
    details    TEXT    NOT NULL DEFAULT '{}',
    created_at TEXT    NOT NULL
);
CREATE INDEX audit_log_entity ON audit_log (entity, entity_id);

-- Change feed for the search index: every write that affects a content's search document
-- appends a row in the same transaction. The index stores the highest sequence it has applied
-- (tantivy commit payload) and catches up from here after a crash.
CREATE TABLE search_changes (
    seq        INTEGER PRIMARY KEY AUTOINCREMENT,
    content_id INTEGER NOT NULL
);
