"""The steady state of the engine: a batched exact-Jacobian Newton solve of the residual
system, its generated and compiled C hot path, and the model as a user sees it.

=====================  ====================================================================
module                 job
=====================  ====================================================================
``model``              :class:`EngineModel`: ``F(w, theta, p) -> (x_s, x_v)`` on batches
``interface``          what an estimator may ask of a steady-state model (typed protocol)
``newton_driver``      the damped Newton-chord iteration, in C (``newton_batch.c``) and numpy
``codegen``            CasADi functions compiled to C shared libraries, cached on disk
``batch_eval``         CasADi functions of one point evaluated over a batch
``guess_table``        starting guesses of the unknowns over the operating envelope
=====================  ====================================================================
"""
