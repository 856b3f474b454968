"""The twin beside every trial: the servo model in step with the joints, and the detector that says when one stops behaving like itself."""
