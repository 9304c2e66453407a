-- ingest: for a video with a variable frame rate, the decoded frame shown at each frame of the
-- constant-rate grid the later stages use (NULL: the decoded frames are that grid).
ALTER TABLE ingest_probes ADD COLUMN source_frames INTEGER[];
