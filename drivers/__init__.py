"""Virtual drivers and riders: scripted manoeuvres, path and speed followers, replay, live input."""
