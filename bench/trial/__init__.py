"""One trial end to end: prepare and check the plan before anything moves, run it through the
engine, write its record and report; and the list of past runs."""
