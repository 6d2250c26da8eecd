"""The names a training run chooses from: models, learning-rate schedules, normalisations,
validation schemes. No imports, so that the CLI's ``--help`` lists them without loading numpy;
:mod:`.train_config` documents what each one means."""

MODEL_KINDS = ("fnn", "cnn", "dcnn", "tcn", "trend")
FLIGHT_MODELS = ("tcn", "trend")  # read a flight table (train_config's docstring)
SCHEDULES = ("plateau", "constant")
NORMALISATIONS = ("auto", "minmax", "condition")
VALIDATIONS = ("auto", "flights", "units")
