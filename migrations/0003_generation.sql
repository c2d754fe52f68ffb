-- Every put writes a new generation (a random 64-bit number), so a replica notices that an
-- object was replaced by reading one integer (ObjectStore::generation) instead of the
-- object. Objects stored before get one each; only inequality matters.
ALTER TABLE objects ADD COLUMN generation INTEGER NOT NULL DEFAULT 0;
UPDATE objects SET generation = random();
