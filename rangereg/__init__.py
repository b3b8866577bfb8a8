"""rangereg: register 3-D range scans with the hybrid simulated annealing + ICP of Luck, Hoff, Underwood and
Little (ICRA 2000).

The repository's folders install under this one name: ``core/`` as ``rangereg.core`` (the engine, never
drawing), ``app/`` as ``rangereg.app`` (the command line and the viser workbench), ``assets/`` as the default
scenes' data. Nothing else lands at site-packages' top level.
"""
