-- lift: the cleanup's measures at each stored step, so that reading them back needs no physics:
-- the deepest geom below the floor (m, 0 if none) and each foot's horizontal slide since the step
-- before (m/s; NaN for a foot not in contact at both steps, and at a fighter's first step).
-- NULL in outputs made before these columns existed.
ALTER TABLE lift_motion ADD COLUMN floor_penetration_m DOUBLE;
ALTER TABLE lift_motion ADD COLUMN slide_left_m_s DOUBLE;
ALTER TABLE lift_motion ADD COLUMN slide_right_m_s DOUBLE;
