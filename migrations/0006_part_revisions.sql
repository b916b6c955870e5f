-- History of parts' geometry (issue 6): every change of a part — created by a selection or
-- through the API, grown, trimmed or replaced with the selection tools, deleted — with its
-- vertex set (serialised RoaringBitmap of original vertex ids) at that revision. Rows outlive
-- the part (no foreign key on part_id), so a deleted part's history stays readable; they go
-- with their model.

CREATE TABLE part_revisions (
    id           INTEGER PRIMARY KEY,
    part_id      INTEGER NOT NULL,
    model_id     INTEGER NOT NULL REFERENCES models (id) ON DELETE CASCADE,
    number       INTEGER NOT NULL,
    -- create | replace | add | subtract | edit (API patch) | delete
    action       TEXT    NOT NULL
                         CHECK (action IN ('create', 'replace', 'add', 'subtract', 'edit', 'delete')),
    -- Selection tool (lasso, markup, heavy_lasso, point), NULL for API writes.
    tool         TEXT,
    kind         TEXT    NOT NULL CHECK (kind IN ('point', 'region')),
    center_x     DOUBLE PRECISION NOT NULL,
    center_y     DOUBLE PRECISION NOT NULL,
    center_z     DOUBLE PRECISION NOT NULL,
    vertex_count BIGINT  NOT NULL DEFAULT 0,
    vertex_set   BLOB,
    -- The view the selection was made from (JSON), if any.
    view         TEXT,
    author_id    INTEGER REFERENCES users (id) ON DELETE SET NULL,
    created_at   TEXT    NOT NULL,
    UNIQUE (part_id, number)
);
CREATE INDEX part_revisions_model ON part_revisions (model_id);
