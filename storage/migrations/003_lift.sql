-- lift: the camera of each shot, world to camera (x_cam = R x_world + t), row-major; where it
-- came from ('calibration' or 'fov' guess) and what the floor said about it.
CREATE TABLE lift_cameras (
    key        VARCHAR NOT NULL,
    video_id   VARCHAR NOT NULL,
    shot       INTEGER NOT NULL,
    source     VARCHAR NOT NULL CHECK (source IN ('calibration', 'fov')),
    K          DOUBLE[9] NOT NULL,
    R          DOUBLE[9] NOT NULL,
    t          DOUBLE[3] NOT NULL,
    height_m   DOUBLE NOT NULL,
    pitch_deg  DOUBLE NOT NULL,
    PRIMARY KEY (key, video_id, shot)
);

-- lift: each fighter's humanoid state at 30 Hz (step k is k / 30 s into the video, whatever its
-- frame rate): qpos (root position, root quaternion w x y z, 28 hinge angles), qvel, the cleaned
-- 3D joints in BlazePose order (x0, y0, z0, x1, ...; world metres, z up) and the foot contacts.
CREATE TABLE lift_motion (
    key            VARCHAR NOT NULL,
    video_id       VARCHAR NOT NULL,
    role           VARCHAR NOT NULL CHECK (role IN ('adversary', 'opponent')),
    step           INTEGER NOT NULL,
    time_s         DOUBLE NOT NULL,
    qpos           FLOAT[35] NOT NULL,
    qvel           FLOAT[34] NOT NULL,
    joints         FLOAT[99] NOT NULL,
    contact_left   BOOLEAN NOT NULL,
    contact_right  BOOLEAN NOT NULL,
    PRIMARY KEY (key, video_id, role, step)
);

-- lift: each fighter's bone lengths (metres), measured from the video.
CREATE TABLE lift_bones (
    key       VARCHAR NOT NULL,
    video_id  VARCHAR NOT NULL,
    role      VARCHAR NOT NULL,
    bone      VARCHAR NOT NULL,
    length_m  DOUBLE NOT NULL,
    PRIMARY KEY (key, video_id, role, bone)
);

-- lift: review media of both humanoids, as artifacts: kind 'video' is an H.264 MP4 of their
-- cleaned motion, one frame per 30 Hz step.
CREATE TABLE lift_media (
    key       VARCHAR NOT NULL,
    video_id  VARCHAR NOT NULL,
    kind      VARCHAR NOT NULL,
    artifact  VARCHAR NOT NULL,
    PRIMARY KEY (key, video_id, kind)
);
