"""Time: grids and the time transformation, the theta-scheme stepper, quasi-static solves."""
