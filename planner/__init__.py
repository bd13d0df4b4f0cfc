"""loggrasp planner package."""
