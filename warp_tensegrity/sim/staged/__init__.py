"""The staged step family: one kernel per stage, every method; bar contact and the striker."""
