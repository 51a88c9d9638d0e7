"""Ego-motion from the road's image motion: the direct parametric estimator (sections 3-4),
its homography and motion model, the IEKF, ego-motion compensation and the baselines."""
