"""The CPU front end: depth hole filling, gravity, segment proposals, lifting."""
