"""Device drivers: one abstract base per device kind, one config per backend, backends registered by name.

`handeye.drivers.robot.registry.ROBOTS` and `handeye.drivers.camera.registry.CAMERAS` map a
config table's ``type`` / ``backend`` to its backend. Vendor SDKs are imported
only when a backend connects, so a machine without OpenNI2 can still run the
simulated cell. Nothing here imports `mocks`.
"""
