#include <iostream>

#include "app.hpp"

int main(int argc, char** argv) {
  return cdpr::fit::run(argc, argv, std::cout, std::cerr);
}
