//! flowgate: the gateway between a PSD camera controller (serial) and pulse-motor boards
//! (CAN) that steers a mobile robot around moving obstacles.
