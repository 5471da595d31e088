"""msarm: control of cable-driven robots whose cables run through sheaths and over pulleys.

Layers (each depends only on those listed before it): ``model``, ``muscle``, ``allocation``,
``plant``, ``control``, ``compensation``, ``tasks``, ``diagnose``, ``io`` and ``cli``.
"""

__version__ = "0.1.0"
