"""needle-hil-bench: the bench itself, in layers (README, "Layout"): robots and their room at the
bottom, then configs, backends, the trial engine and its reports, the features, and the CLI on top."""
