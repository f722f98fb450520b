"""What every user-facing command of the project shares, on the standard library only:
how it writes the files a user asked for (:mod:`fleetgate.userio.files`) and how it ends
(:mod:`fleetgate.userio.exits`).

It holds no fleetgate logic, so the independent trace checker and the robot client may use it
too (``tests/test_import_rules.py``).
"""
