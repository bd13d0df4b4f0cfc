"""loggrasp field package."""
