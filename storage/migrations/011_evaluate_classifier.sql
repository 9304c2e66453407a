-- evaluate: the held-out two-sample classifier test (tasks/evaluate/two_sample.py), the headline
-- "moves like the footage" figure: a fresh classifier's AUC at telling 1-second windows of the
-- adversary's held-out footage from 1-second windows of a simulated fighter, policy 'adversary'
-- (trained agent 0), 'untrained', 'still' (agent 0 holding its guard) or 'replay' (a tracker
-- replaying the held-out clips). 0.5: cannot tell them apart; 1: always can. auc, auc_low and
-- auc_high (its 95 % bootstrap interval) are NULL when the test could not be made, and reason
-- says why (no held-out footage, too few windows, no tracker).
CREATE TABLE evaluate_classifier (
    key                VARCHAR NOT NULL,
    video_id           VARCHAR NOT NULL,
    policy             VARCHAR NOT NULL,
    auc                DOUBLE,
    auc_low            DOUBLE,
    auc_high           DOUBLE,
    real_windows       INTEGER NOT NULL,
    simulated_windows  INTEGER NOT NULL,
    reason             VARCHAR,
    PRIMARY KEY (key, video_id, policy)
);
