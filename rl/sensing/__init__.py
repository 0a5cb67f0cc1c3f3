"""What the learned pilot senses, shared by the env and the flying pilot."""
