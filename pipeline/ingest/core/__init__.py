"""The streaming pass of ingest: messages handled one by one through the gates and checks
into the index."""
