-- evaluate: what gives a simulated fighter away in the two-sample test (tasks/evaluate/two_sample.py
-- telltales): the window features whose means differ most between the held-out footage and the
-- simulated fighter, in pooled standard deviations, e.g. "left_ankle_y_mean +3.2, ..."; NULL
-- where the test was not made.
ALTER TABLE evaluate_classifier ADD COLUMN telltales VARCHAR;
