"""The vehicle kit: parts any vehicle assembly reuses (tyres, linkages, brake, powertrain, steering,
actuators, the sensor model, index layouts). A part knows nothing of the vehicle it is fitted to."""
