"""One robot's filter: the state (a window of SE(3) poses and object landmarks, the one door to
its covariance), the stereo model and its Jacobians, the batched updates, where Jacobians are
evaluated (standard, first-estimate, ideal, observability-constrained), objects retired into a
persistent map as consider states, the views of each object, and the observability of the team
filter."""
