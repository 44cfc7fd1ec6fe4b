"""Motion models of the differential base: body twists and wheel speeds (`diffdrive`), and the
virtual car that a differential base emulates (`car`, docs/motion-models.md).

Pure: nothing here reads a clock or touches the bus; every function takes the time it needs.
hwbridge turns every motion command into wheel speeds with these, and nothing else does.
"""
