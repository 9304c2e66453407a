-- stage_runs also notes when a stage starts computing ('running'), with the process doing it
-- (worker = 'host:pid'), so the dashboard can show work in progress and tell a live run from
-- one whose process was killed. DuckDB cannot change a CHECK constraint in place, so the table
-- is rebuilt.
CREATE TABLE stage_runs_new (
    run_id        VARCHAR NOT NULL,
    video_id      VARCHAR NOT NULL,
    stage         VARCHAR NOT NULL,
    key           VARCHAR NOT NULL,
    state         VARCHAR NOT NULL CHECK (state IN ('running', 'done', 'cached', 'failed')),
    error         VARCHAR,
    created_at    TIMESTAMP NOT NULL,
    worker        VARCHAR
);
INSERT INTO stage_runs_new SELECT *, NULL FROM stage_runs;
DROP TABLE stage_runs;
ALTER TABLE stage_runs_new RENAME TO stage_runs;
