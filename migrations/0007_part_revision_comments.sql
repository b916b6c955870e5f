-- Every write of a part is a revision (issue 10): revisions keep the part's camera and the
-- author's comment too.
ALTER TABLE part_revisions ADD COLUMN camera TEXT;
ALTER TABLE part_revisions ADD COLUMN comment TEXT;
