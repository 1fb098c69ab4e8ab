"""nni_plant_sim."""
