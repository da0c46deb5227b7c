"""The vehicle model: configuration, suspension kinematics, tyres, brakes, powertrain, steering, sensors."""
