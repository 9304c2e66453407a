-- evaluate: the two-sample test against two references (issue 48): reference 'footage' (the
-- adversary's held-out footage, the rows there were) and 'replay' (the dataset's tracker
-- replaying those clips: the physically valid version of the same footage). Policy 'train' is
-- the reference's own train split (train footage; the replay of the train clips), the level a
-- perfect answer reaches. feature_gap: the mean absolute difference of the window features'
-- means, in the reference's standard deviations (tasks/evaluate/two_sample.py feature_gap),
-- NULL where the test was not made. The primary key takes the reference, so the table is made
-- again and its rows kept as the footage's.
CREATE TABLE evaluate_classifier_by_reference (
    key                VARCHAR NOT NULL,
    video_id           VARCHAR NOT NULL,
    reference          VARCHAR NOT NULL,
    policy             VARCHAR NOT NULL,
    auc                DOUBLE,
    auc_low            DOUBLE,
    auc_high           DOUBLE,
    real_windows       INTEGER NOT NULL,
    simulated_windows  INTEGER NOT NULL,
    reason             VARCHAR,
    telltales          VARCHAR,
    feature_gap        DOUBLE,
    PRIMARY KEY (key, video_id, reference, policy)
);
INSERT INTO evaluate_classifier_by_reference
SELECT key, video_id, 'footage', policy, auc, auc_low, auc_high, real_windows,
       simulated_windows, reason, telltales, NULL
FROM evaluate_classifier;
DROP TABLE evaluate_classifier;
ALTER TABLE evaluate_classifier_by_reference RENAME TO evaluate_classifier;
