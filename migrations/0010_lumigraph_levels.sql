-- Refinement levels of the image repository (engine/src/lumigraph/grid.rs): level 0 is the
-- grid the build job renders; a finer level halves the spacing once per level near the model,
-- and its images are rendered when first asked for. An image is keyed by its level as well,
-- and a point is always named by its coarsest level.
CREATE TABLE lumigraph_images_new (
    model_id   INTEGER NOT NULL REFERENCES lumigraphs (model_id) ON DELETE CASCADE,
    level      INTEGER NOT NULL DEFAULT 0 CHECK (level >= 0),
    x          INTEGER NOT NULL,
    y          INTEGER NOT NULL,
    z          INTEGER NOT NULL,
    d          INTEGER NOT NULL CHECK (d BETWEEN 0 AND 5),
    kind       TEXT    NOT NULL CHECK (kind IN ('image', 'empty', 'inside')),
    sha256     TEXT,
    bytes      BIGINT  NOT NULL DEFAULT 0,
    PRIMARY KEY (model_id, level, x, y, z, d),
    CHECK ((kind = 'image') = (sha256 IS NOT NULL))
) WITHOUT ROWID;
INSERT INTO lumigraph_images_new (model_id, level, x, y, z, d, kind, sha256, bytes)
    SELECT model_id, 0, x, y, z, d, kind, sha256, bytes FROM lumigraph_images;
DROP TABLE lumigraph_images;
ALTER TABLE lumigraph_images_new RENAME TO lumigraph_images;
CREATE INDEX lumigraph_images_sha ON lumigraph_images (sha256);
