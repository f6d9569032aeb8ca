"""The vehicle FMU's sources, shipped with the package so an installed tirefilter can build it.

- `variables.py`: the one table of the FMU's variables;
- `c/`: the C sources (package data): `vehicle_model.c` the equations with no FMI code,
  `var_access.c` get/set by value reference, `fmi2_glue.c` / `fmi3_glue.c` the FMI entry points;
- `build.py`: generates the header, `modelDescription.xml` and the FMI 3.0 stubs from the
  table, compiles with the system C compiler and zips the FMUs into `default_out_dir()`
  (`tirefilter fmu build vehicle`). docs/fmu.md describes the FMU.
"""
