"""Plain scripts a user could write instead of ``posefix correct``: the whole-process peers
of ``benchmarks.engine_io`` (run as ``python benchmarks/peers/<name>.py IN.csv EDITS.json OUT.csv``)."""
