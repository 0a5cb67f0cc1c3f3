"""What the vehicle senses: its sensors (IMU, barometer, GNSS, heading aid, lidar) as specified parts, the ray
caster they see the true city with, the navigation filter that turns their readings into an estimate, and
`onboard.Onboard`, which steps them beside the simulator. See docs/sensing.md."""
