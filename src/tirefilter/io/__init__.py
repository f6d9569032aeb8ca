"""The file formats a run reads and writes, apart from the code that runs it.

- `results`: the Result CSV (one row per estimator sample: estimates, sensors, truth),
  written incrementally (`ResultWriter`) and read whole or chunk by chunk.
- `csv_format`: rows of floats as CSV text, and the helper process that formats a long
  run's rows beside it (stdlib only: `ResultWriter` runs the file as a script).
- `friction`: the friction CSV (snapshots of a friction estimator's curves).
- `log`: the Log CSV (a recorded drive: the replay's input), its reader, checks and writer.

docs/usage.md describes each format. The package is `tirefilter.io`; nothing here is named
after, or shadows, the standard library's `io` (imports are absolute).
"""
