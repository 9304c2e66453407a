-- pace: each fighter's pelvis speed (m/s) at the configured percentile over the video.
CREATE TABLE pace_speeds (
    key VARCHAR NOT NULL,
    video_id VARCHAR NOT NULL,
    role VARCHAR NOT NULL,
    speed_m_s DOUBLE NOT NULL,
    PRIMARY KEY (key, video_id, role)
);
