"""Recording: the rerun recording of a run and the viewer."""
