"""The trial engine, backend-agnostic: the control loop (runner), its log, the safety interlocks
checked every cycle, signal handling, ground truth and where the needle ended up."""
