"""pe_drake: persistently exciting trajectories, identification and diagnosis on Drake."""

__version__ = "0.1.0"
