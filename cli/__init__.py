"""hyprog's command-line interface: thin typer commands over the library.

No package imports ``cli``. Heavy modules (CasADi, the engine model, pandas) are imported
inside the commands, so ``hyprog --help`` answers at once.
"""
