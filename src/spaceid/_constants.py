"""Names and defaults that the library defines once and the command line shows when it starts
(option choices, defaults, help): plain values, importing nothing, so that ``spaceid --help``
does not load NumPy's estimation stack. The library modules import them from here; their
meaning is documented where they are used (the module named beside each)."""

ESTIMATORS = ("ml", "wls", "iv", "tls", "ols", "angles")
"""Estimators of :func:`spaceid.estimation.identify` (:mod:`spaceid.estimation._estimators`)."""

KNOT_SPACING = 0.05
"""Default knot spacing of the joint-path splines of the ``angles`` estimator [s]
(:mod:`spaceid.estimation._angles`). A cubic spline through a motion of angular frequency
``omega`` and amplitude ``a`` misses it by about ``5 a (omega d)^4 / 384`` at spacing ``d``: below
1e-6 rad at 0.05 s for Cepheus' motions (harmonics up to 0.6 Hz within the joint limits), far
below encoder noise, so the splines add no bias. Finer knots cost time but no accuracy: the bound
is the same to 1e-6 from 0.1 s down to 0.02 s on Cepheus (the nuisance's extra freedom is at
frequencies the parameters do not see; tests/test_angles.py)."""

DRIFT_KINDS = ("torque", "viscous", "coulomb")
"""Drift terms of the momentum (:mod:`spaceid.estimation._drift`)."""

DESIGN_CRITERIA = ("cond", "logdet", "dopt", "crb")
"""Criteria of :func:`spaceid.motion.design_excitation`, the keys of
:data:`spaceid.motion._criteria.CRITERIA`."""

JOINT_RATES = ("auto", "velocity", "differentiate")
"""Joint-rate sources of a bag log (:func:`spaceid.data.to_log`)."""

BASE_RATES = ("attitude", "gyro")
"""Base-rate sources of a bag log (:func:`spaceid.data.to_log`'s ``base_rate``): the attitude differentiated, or
the angular velocity its pose messages measured (an Odometry's twist, an IMU's: the gyro's)."""

JOINT_RATE_POLICY = "differentiate"
"""Default joint-rate source of a bag log (:func:`spaceid.data.to_log`): the encoder angles,
differentiated. The velocity field of a JointState is often a one-tick encoder difference (on the
Cepheus twin a count per millisecond is 1.5 rad/s on the wheel): on the twin experiment's bags
(seeds 0-2, 29 samples) the worst parameter error was 7.6-37 % from differentiated angles and
77-227 % from the published velocities. ``spaceid identify``, ``spaceid validate`` and the
experiment all read bags with it."""

BAG_FORMATS = ("ros1", "ros2", "mcap")
"""Bag formats that :func:`spaceid.data.write_bag` writes (:data:`spaceid.data.FORMATS`)."""

DEFAULT_JOINT_TOPIC = "/joint_states"
"""Topic of ``sensor_msgs/JointState`` (``joint_state_controller``'s default)."""

DEFAULT_POSE_TOPIC = "/vrpn_client_node/cepheus/pose"
"""Topic of the base's ``geometry_msgs/PoseStamped`` (``vrpn_client_ros``, rigid body ``cepheus``)."""

EXPORT_FORMATS = ("urdf", "yaml", "mjcf")
"""Output formats of :func:`spaceid.identified.write_export`."""

FALSE_ALARM_RATE = 1e-5
"""Default false alarms per sample of the change monitor under no change (one per 10^5 samples:
17 min at 100 Hz; :mod:`spaceid.estimation._monitor`)."""

CHANGE_RATIO = 4.0
"""Default innovation variance ratio the monitor's CUSUM is tuned to (innovations twice their
predicted std)."""

WARMUP = 200
"""Least samples of a monitored segment's warm-up by default (2 s at 100 Hz): shorter ones leave
the estimate too loose for the normalisation of the residuals that follow (false alarms early in
a segment)."""
