-- Who is computing which stage output now: one row per output key while a process computes it
-- (worker = 'host:pid'), so that a second run of the same output waits for the first and reuses
-- what it commits, instead of computing it again. A row whose process is gone is taken over.
CREATE TABLE stage_claims (
    stage       VARCHAR NOT NULL,
    video_id    VARCHAR NOT NULL,
    key         VARCHAR NOT NULL,
    worker      VARCHAR NOT NULL,
    claimed_at  TIMESTAMP NOT NULL,
    PRIMARY KEY (stage, video_id, key)
);
