"""Flying an episode: the pilot registry and plug-ins (`pilots`), the one episode loop (`episode_loop`),
per-episode seeds (`seeding`) and the flight-model demo (`demo`)."""
