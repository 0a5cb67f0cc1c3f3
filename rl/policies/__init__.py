"""Policy folders: their format (`folder`), safe reader (`reader`), network, and the shipped ones."""
