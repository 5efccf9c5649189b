"""dobkit: disturbance-observer-based trajectory tracking of a surgical robot arm, on python-control."""
__version__ = "0.1.0"
