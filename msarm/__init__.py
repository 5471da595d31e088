"""msarm: control of cable-driven robots whose cables run through sheaths and over pulleys.

Parts: ``model`` (the robot model: MuJoCo and Pinocchio), ``muscle`` (Hill muscles, cable
geometry), ``allocation`` (muscle-force allocation), ``plant`` (the simulated robots),
``control``, ``tasks`` (tasks, runs, metrics), ``compensation`` (the feedforward
compensator), ``diagnose`` (the sim-to-real gap diagnosis), ``cdpr`` (the cable-driven
parallel robot), ``io`` (configs and logs, used by most of the others) and ``cli``. The
robot model builds its muscles with ``muscle.hill`` and the muscle geometry works on the
model; the compensator's sheath stage uses the diagnosis's capstan terms; the command line
depends on everything.
"""

__version__ = "0.1.0"
