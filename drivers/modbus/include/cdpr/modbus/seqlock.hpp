// The sequence lock moved to core/ (cdpr/core/seqlock.hpp, cdpr::SeqLock). This header keeps
// code written before the move compiling; new code includes cdpr/core/seqlock.hpp.
#pragma once

#include "cdpr/core/seqlock.hpp"

namespace cdpr::modbus {
using cdpr::SeqLock;
}  // namespace cdpr::modbus
