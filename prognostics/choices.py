"""The names a training run chooses from: models, learning-rate schedules, normalisations,
validation schemes. No imports, so that the CLI's ``--help`` lists them without loading numpy;
:mod:`.train_config` documents what each one means."""

MODEL_KINDS = ("fnn", "cnn", "dcnn", "tcn", "trend", "similarity")
FLIGHT_MODELS = ("tcn", "trend", "similarity")  # read a flight table (train_config's docstring)
LIBRARY_MODELS = ("similarity",)  # no network: a library of training units (similarity.py)
SCHEDULES = ("plateau", "constant")
NORMALISATIONS = ("auto", "minmax", "condition")
VALIDATIONS = ("auto", "flights", "units")
