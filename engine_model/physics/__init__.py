"""The physics of the engine, built symbolically in CasADi (the residual system the solver
drives to zero).

=====================  ====================================================================
module                 job
=====================  ====================================================================
``atmosphere``         International Standard Atmosphere, free-stream total conditions
``gas``                real-gas properties of air and combustion products
``hermite``            piecewise-cubic schedules on floats, arrays and CasADi symbols
``maps``               smooth analytic component maps, scaled at the design point
``components``         inlet, fan, compressors, burner, turbines, ducts, nozzles
``schedule``           the throttle schedule and the limiters
``bleed_schedule``     the booster's variable-bleed-valve schedule
``design``             the design point of the 90,000 lbf class turbofan
``turbofan``           the two-spool engine assembled from its components
``health_index``       N-CMAPSS's health index from the health parameters
``effect_base``        the optional physical effects' base, registry and hooks
``effect_library``     the library of optional effects
``effects``            the public façade of the effects (import effects from here)
``stage_stacking``     a mean-line stage stack: a second model of a fouled compressor
=====================  ====================================================================
"""
