"""m3gd package."""
