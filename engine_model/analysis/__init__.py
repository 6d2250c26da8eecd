"""Studies of the engine model itself: the envelope sweep, health signatures, the model
against a reference table of operating points, random operating points.

=====================  ====================================================================
module                 job
=====================  ====================================================================
``sampling``           random operating points of the civil flight envelope
``envelope``           solve random envelope points and report convergence and ranges
``signatures``         how each health parameter moves the gas-path channels
``reference``          the model against a reference table (C-MAPSS FD002 by default)
=====================  ====================================================================
"""
