"""The sim-to-real gap diagnosis (in progress): where the gap lies and which effect causes it.

Modules so far:

- ``residuals``: per-sample residuals of a log against the nominal model (the joint-torque
  residual ``tau_MS - ID``, the cable length error, a short-window replay of the nominal
  dynamics driven by the logged tensions); never opens the ground-truth sidecar.
- ``where``: the residual energy broken down by channel, phase of motion, load and region of
  posture, as a ranked table and a heat map.
- ``signals``, ``effects``, ``fitting``: the library of candidate effects (Coulomb, viscous,
  Stribeck, capstan, cogging, sensor bias and scale, first-order delay, mass and inertia
  error through Pinocchio's regressor), each a parametric term fitted by least squares or
  IPOPT (casadi), scored on held-out samples, with bootstrap over runs.

- ``builder``: the signals and the residual of several logs, with run labels.
- ``select``: forward selection of candidate effects by the share of held-out residual
  variance they explain (a term is added while it gains more than 0.02), and the gap before
  and after on the held-out runs (``msarm diagnose``).

Still to come (issue 7): plausibility of the fitted parameters (later picks can compensate
each other), the phase and posture breakdown in the report, the withheld-effect benchmark
with a PySINDy baseline, users' effects example.
"""
