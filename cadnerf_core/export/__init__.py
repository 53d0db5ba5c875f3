"""Stage 9: outputs: poses, transforms.json, views, orbit video, mesh and the results bundle."""
