"""The fleet simulator: N-CMAPSS-like run-to-failure fleets from the engine model.

=====================  ====================================================================
module                 job
=====================  ====================================================================
``flight_profiles``    the scenario descriptors ``w`` of one flight (climb, cruise, descent)
``degradation``        a unit's health trajectory: initial wear, normal and abnormal
                       degradation, end of life when the health index reaches 0
``sensor_noise``       measurement noise of the measured channels
``fleet``              presets (``tiny``, ``ds02``), units in parallel, effects the
                       calibration model may lack, written as a dataset
=====================  ====================================================================
"""
