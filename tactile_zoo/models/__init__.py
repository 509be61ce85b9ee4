"""The model zoo: one model family per module; importing a module registers its models."""

# importing these modules registers their models
