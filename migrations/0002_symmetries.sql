-- Format 5 objects carry their symmetries (JSON, as in the manifest); NULL: unknown
-- (objects stored before, or by an older program).
ALTER TABLE objects ADD COLUMN symmetries TEXT;
