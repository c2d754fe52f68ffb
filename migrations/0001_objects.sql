-- Schema version 1 of the SQLite object store (src/store/sqlite.rs).
-- Migrations run in file-number order, each in its own transaction, and
-- `PRAGMA user_version` records how many have been applied.

-- One row per stored object. The list columns repeat fields of the manifest so that
-- `list` and `info` never parse a manifest or touch a blob.
CREATE TABLE objects (
    id          TEXT    NOT NULL PRIMARY KEY,
    manifest    TEXT    NOT NULL,   -- codec manifest (JSON)
    created_at  INTEGER NOT NULL,   -- unix seconds, from the manifest
    bytes       INTEGER NOT NULL,   -- manifest + every chunk, in bytes
    units       TEXT    NOT NULL,   -- units of the source mesh: 'mm', 'cm' or 'm'
    diameter_m  REAL    NOT NULL,
    backbone    TEXT    NOT NULL,   -- BackboneIdentity (JSON)
    templates   INTEGER NOT NULL    -- template count
) STRICT;

-- The encoded bytes of each object, split into chunks of at most 4 MiB so that no row is
-- huge. A part is 'tensors' (the safetensors buffer, which also holds the mesh arrays) or a
-- texture name from the manifest ('textures/0.png'); its chunks are numbered 0, 1, 2, ...
-- The primary key index also serves the cascade and the ordered read of one object.
CREATE TABLE chunks (
    object_id   TEXT    NOT NULL REFERENCES objects(id) ON DELETE CASCADE,
    part        TEXT    NOT NULL,
    seq         INTEGER NOT NULL CHECK (seq >= 0),
    data        BLOB    NOT NULL,
    PRIMARY KEY (object_id, part, seq)
) STRICT;
