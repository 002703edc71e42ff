"""Device drivers: one abstract base per device kind, one config per backend.

Vendor SDKs are imported only inside the factory branch that needs them, so
that a machine without OpenNI2 can still run the simulated cell.
"""
