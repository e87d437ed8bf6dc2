"""armbench fakes package."""
