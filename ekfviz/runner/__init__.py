"""Running a filter over events: the loop of steps that emits one record per event."""
