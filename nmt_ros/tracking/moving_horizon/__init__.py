"""Moving-horizon (fixed-lag) estimation of Stage 1 on the muscle-driven model.

``MovingHorizonEstimator`` (``estimator``) is the streaming object the nodes and the batch
tools drive; ``window`` holds the sliding window and its Gauss-Newton steps; ``residuals``,
``point_functions``, ``spline`` and ``normal_equations`` are its parts.
"""
