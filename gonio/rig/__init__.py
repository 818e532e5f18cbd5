"""Hardware layer: device interfaces (:mod:`gonio.rig.interfaces`), clocks, drivers, kinematics."""
