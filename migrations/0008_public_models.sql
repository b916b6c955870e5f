-- Public read-only access per model (issue 16): anonymous visitors may view a public model,
-- search and read the information on its parts, never edit.
ALTER TABLE models ADD COLUMN public INTEGER NOT NULL DEFAULT 0 CHECK (public IN (0, 1));
