-- The migrations of stages that bring their own tables (`tasks.registry.Stage.migrations`),
-- numbered per stage: which of them this database has applied.
CREATE TABLE stage_migrations (
    stage VARCHAR NOT NULL,
    version INTEGER NOT NULL,
    name VARCHAR NOT NULL,
    applied_at TIMESTAMP NOT NULL,
    PRIMARY KEY (stage, version)
);
