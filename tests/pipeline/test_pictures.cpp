// The run's pictures: a contact sheet of non-square frames fills every cell.
#include <catch2/catch.hpp>

#include <cmath>

#include "orbitforge/pipeline/report/pictures.hpp"

using namespace orbitforge;

TEST_CASE("contact_sheet: 896x512 frames fill their cells, no empty bands", "[pipeline][pictures]") {
  const int cell_w = 128, cell_h = 73;  // 896x512 at 128 wide
  const Image<float> sheet = contact_sheet(2, 361, cell_w, cell_h, [](int row, int) {
    return Image<float>(896, 512, 3, row == 0 ? 0.7f : 0.4f);
  });
  const int pad = 2;
  CHECK(sheet.width == 12 * (cell_w + pad) + pad);
  CHECK(sheet.height == 2 * (cell_h + pad) + pad);
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 12; ++c) {
      const int x0 = pad + c * (cell_w + pad), y0 = pad + r * (cell_h + pad);
      int wrong = 0;
      for (int y = y0; y < y0 + cell_h; ++y)
        for (int x = x0; x < x0 + cell_w; ++x) wrong += std::abs(sheet(x, y, 1) - (r == 0 ? 0.7f : 0.4f)) > 1e-4f;
      INFO("row " << r << " column " << c);
      CHECK(wrong == 0);
    }
  // A view that was not rendered leaves its cell as background.
  const Image<float> partial =
      contact_sheet(1, 361, 16, 9, [](int, int view) { return view == 0 ? Image<float>(32, 18, 3, 1.0f) : Image<float>(); });
  CHECK(partial(pad + 1, pad + 1, 0) == 1.0f);
  CHECK(partial(pad + (16 + pad) + 1, pad + 1, 0) < 0.2f);
}
