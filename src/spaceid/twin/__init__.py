"""Torque-driven digital twin of the Cepheus air-bearing emulator: plant, controllers, sensors and
effects.

The twin integrates the rigid-body dynamics of a planar model (default the ``cepheus-rw``
preset: base, reaction-wheel rotor, two-link arm) whose base floats on the granite table in x,
y and yaw, under the torques of ros_control-like effort controllers, and records what the
robot's sensors would publish: encoder joint states and the motion-capture pose of the base.

API
---
Everything is a free function or a frozen dataclass::

    settings = TwinSettings()                       # the realistic twin; every value overridable
    a = spin_up(170.0, settings=settings, seed=1)   # rest -> wheel at 170 rad/s relative to the base
    b = run_twin(load_trajectory("paper-table2"), duration=6.0, state=a.state,
                 settings=settings, seed=2)         # exciting trajectory (tf = 5 s), then hold
    run = join_runs(a, b)                           # one continuous recording
    run.recording      # spaceid.data.Recording: /joint_states (50 Hz) and mocap poses
    run.truth          # spaceid.data.Log at the control rate (planar, true q, qd, yaw, rate)
    run.base_position, run.base_velocity, run.effort, run.co2_mass   # more true histories
    run.state          # TwinState at the end: the start of the next phase

    grasping = replace(settings, capture=Capture(time=4.0, mass=0.5, position=(0.6, 0.2)))
    c = run_twin(load_trajectory("paper-table2"), duration=6.0, settings=grasping, state=a.state)
    c.meta["capture"]  # the truth: payload in the link's frame, grasp time, parameters before/after

* :func:`run_twin` ``(reference=None, *, duration, wheel_speed=None, settings, state, seed, effort,
  controller)`` runs one phase from ``state`` (default: at rest at the origin, full tank);
  ``reference`` drives the position-controlled joints, ``wheel_speed`` [rad/s] the
  velocity-controlled ones, ``effort`` adds feed-forward efforts to the position loops, and
  ``controller(t, q, qd, base_yaw, base_wz) -> efforts`` replaces the effort controllers with a
  state-feedback law called every control tick (encoder readings, their one-tick difference,
  the true base yaw and rate; efforts of every joint, saturated and held over the tick).
* :func:`spin_up` ramps the wheel set point to ``speed`` and lets it settle, arm holding.
* :func:`join_runs` concatenates consecutive phases into one run.
* :func:`planned_feedforward` plans feed-forward efforts offline from a model (no state read),
  for ``run_twin(..., effort=...)``.
* :func:`computed_torque` is a joint computed-torque law through the free-floating ``H*`` and
  bias torque of any model (an identified one, the true or a CAD prior's ``pi``), for
  ``run_twin(..., controller=...)`` (docs/theory/control.md).
* :func:`planar_pinocchio` builds the Pinocchio model (root PX, PY, RZ) and
  :func:`drained_model` the :class:`~spaceid.models.Model` with a partly empty CO2 tank.
* ``TwinSettings(capture=Capture(time, ...))`` makes the end effector grasp a free-floating
  payload (:func:`payload_pose` where it is before; :func:`place_payload` puts it at the gripper
  at the grasp) in a plastic impact that conserves the total momentum (:func:`table_momentum`);
  the run then integrates the combined system and records the truth in ``meta["capture"]``
  (docs/theory/capture.md).

Structure
---------
One private module per part, each building on the ones before it: the plant, the controllers,
sensors and effects that act on it, and the run that ties them together in the hardware loop;
the settings parametrise them all.

* ``_settings``: :class:`TwinSettings` and its parts; their docstrings carry every assumed value
  (units, defaults and where they come from).
* ``_plant``: the planar Pinocchio model, the base inertia as the tank drains, the RK4 step of
  the articulated-body algorithm; the coordinates and integration accuracy.
* ``_controllers``: set points from the reference and wheel speed, the PD/PI effort controllers,
  the optional inverse-dynamics feed-forward, the feed-forward planned offline and the
  computed-torque law for the controller hook.
* ``_sensors``: encoder quantisation and ``/joint_states``, motion capture with noise, latency
  and dropped frames; time stamps.
* ``_effects``: joint and air-bearing friction, torque limits, thrusters and the CO2 tank, table
  tilt.
* ``_capture``: the grasp of a payload: its free flight, its parameters in the grasping link's
  frame, the impact (generalised momentum conserved) and the truth record.
* ``_run``: :class:`TwinState`, :class:`TwinRun`, the hardware loop (one tick: encoders,
  controllers, saturation, friction and thrust, RK4 step, tank), :func:`run_twin`,
  :func:`spin_up`, :func:`join_runs`; phases.

The servicer twin
-----------------

The spatial counterpart (docs/theory/twin-spatial.md): a free-floating robot (default the
``servicer-dual`` preset) under computed torque through a CAD model 15 % off, with encoders,
a star tracker and gyros::

    settings = ServicerSettings()                          # every value overridable
    run = run_servicer(trajectory, duration=120.0, settings=settings,
                       state=ServicerState(momentum=(1.0, -2.0, 1.5)), seed=1)
    run.recording      # joint states (no velocities) and star-tracker frames
    run.gyro           # gyro samples at the joint-state stamps
    run.truth          # spaceid.data.Log at the control rate (spatial), run.momentum its momentum
    log = servicer_log(run, settings)                      # read as a lab reads it

* :func:`run_servicer` flies one phase; :class:`ServicerState` starts it (a run's ``state``
  continues it); :class:`ServicerRun` holds the streams, the truth and ``meta`` (seeds, momentum
  drift, tracking error, frames lost).
* :func:`servicer_log` reads the streams (:func:`spaceid.data.to_log`, the base rate from the
  gyros or the attitude); :func:`cad_model` is the lab's model the controllers use.
* :class:`ServicerSettings` gathers :class:`JointControl`, :class:`JointEncoders`,
  :class:`StarTracker`, :class:`Gyro` and :class:`TorqueLimits`; ``_servicer`` holds the run,
  ``_sensors`` the star tracker and gyros, ``_plant`` the free-flyer kinematics
  (:func:`free_flyer_rate`) for the same RK4 stepper.

References
----------
The Cepheus paper (NTUA Control Systems Lab; see docs/citing.md):
sections "The NTUA CSL emulator" and "Experiment results": three air
bearings fed with CO2 from an on-board tank (1.5 kg full, 60 bar) that also feeds three pairs of
opposed thrusters at 120 deg; a reaction wheel with I_rw = 0.00197372 kg m^2 spun to 170 rad/s;
arm joints under ros_control ``effort_controllers/JointPositionController`` (PD) and the wheel
under ``effort_controllers/JointVelocityController`` (PI); tf = 5 s. docs/theory/scale.md (reaction wheel momentum).
"""

from . import _settings, _plant, _controllers, _effects, _capture, _run, _servicer
from ._settings import *  # noqa: F403
from ._plant import *  # noqa: F403
from ._controllers import *  # noqa: F403
from ._effects import *  # noqa: F403
from ._capture import *  # noqa: F403
from ._run import *  # noqa: F403
from ._servicer import *  # noqa: F403

__all__ = (_settings.__all__ + _plant.__all__ + _controllers.__all__ + _effects.__all__ + _capture.__all__
           + _run.__all__ + _servicer.__all__)
