"""The runs behind the commands: open the devices, loop over poses or samples, write the session.

One module per run (`calibrate`, `monitor`, `demo`, `plan`, `replay`,
`verify`). Each returns a result object the command prints; known errors are
raised as `handeye.calib.errors.HandeyeError` subclasses, which the command line maps
to one line and exit status 1.
"""
