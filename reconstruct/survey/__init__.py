"""The survey stage: RTK GNSS log-end points with their reported accuracies (:mod:`.gnss`)."""
