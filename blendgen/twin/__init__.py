"""The twin, the virtual place objects are planned and rendered in (bpy-free): its model and
queries (`model`), its YAML schema (`schema`), and the maps it is read from (`maps`: OpenDRIVE,
OpenStreetMap); `command` is `blendgen twin import|show`."""
