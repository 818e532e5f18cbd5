"""The virtual rig: servo-bus and controller emulators on pseudo-terminals, a rendering camera,
a simulated clock and fault injection. ``gonio`` never imports ``sim``; ``sim`` may import gonio's
physics core and its device interfaces (to be a drop-in twin of the real devices)."""
