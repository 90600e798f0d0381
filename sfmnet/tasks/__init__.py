"""What a run does with its fitted models: one task per kind of run (``task=`` in the config)."""
